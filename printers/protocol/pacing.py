"""When the worker may wait before reading: the bytes still on their way out, sans-IO.

A serial link carries baud/10 bytes a second. Bytes the host wrote and the UART has
not sent yet keep the firmware fed, so waking for every reply while they last buys
the link nothing: each wake-up costs the worker the same (a system call, a turn of
its loop, a write of one line), and on a small computer driving many printers that
fixed cost is most of the CPU. The pacer says how long the worker may wait so that
one wake-up takes every reply that came meanwhile and refills the window at once.

Rules of the Pacer (`now` is always passed in; it reads no clock):

P1  Bytes go out one after another at 10/baud seconds each: a write at *now* ends
    at max(now, the end of the previous writes) + size * 10/baud (`busy_until`).
P2  While at least two lines are in flight and the wire is busy until t, the worker
    reads no sooner than t - margin (`read_at`): the margin covers waking up and
    refilling the window before the wire runs dry. One line in flight: P5.
P2a The margin is MARGIN_FACTOR times the worker's own turnaround (a moving average
    of how late the write after a paced wake-up came, sleep overshoot included),
    kept between MIN_MARGIN and MAX_MARGIN: a slow or busy computer wakes earlier
    and gathers fewer replies, but does not let the wire run dry.
P4  A read that ended inside a reply line: the rest of the line comes at the baud
    rate too. The worker waits, in the same turn of its loop, until a line as long
    as the recent ones (`reply_bytes`, a moving average of whole lines read) would
    be complete (`rest_at`), and reads again: a reply cut in two costs one turn.
P5  With one line in flight (ping-pong, the only flow stock Marlin offers, or the
    end of a job) its reply cannot be whole before the line has left the wire, the
    firmware has answered (`lag`) and a reply line as long as the recent ones has
    come back: the worker reads no sooner (`read_at`), so one wake-up takes the
    whole reply where it took one for the reply's first byte and one for the rest
    (P4); each wake-up costs the worker more than the rest of its turn. The first
    read after a lone line teaches `lag` (`received`), from when the reply's first
    byte came (len(data) byte times before the read): a read made at once (no
    wait, or P3's sample, one wait in PROBE_EVERY) that cut the reply measures
    it; one that found it whole bounds it from above (lowered to that bound: a
    link faster than its baud rate soon reads at once); a read after a wait that
    cut the reply raises `lag` a part of the way to it (LAG_RISE: the firmware
    answers more slowly than thought, or was slow once); a wait that found it
    whole teaches nothing. An answer later than
    LONGEST_WAIT is a long command (G28, M109), not the firmware's pace: nothing is
    learned from it.
P3  A link faster than its baud rate (a board's native USB port ignores it): a read
    is a sample when the model says more than SLACK_BYTES are still to go out. A
    sample in which the firmware has acknowledged more than SLACK_BYTES of them is
    evidence; EVIDENCE samples of it in a row (one that agrees with the model
    starts the count again) prove the model wrong for this connection, and P2 and
    P5 are off until `reset()`. One sample is no proof: a stale `ok` left in the
    port's buffer acknowledges a line at once, and a host preempted between its write
    and its clock misjudges the write. Every PROBE_EVERY-th wait of P2 and P5 is
    skipped (the worker reads as replies come), so a fast link shows itself while
    paced.
"""

from __future__ import annotations

__all__ = ["MAX_MARGIN", "MIN_MARGIN", "Pacer"]

#: Bounds of the margin (s) before the wire runs dry at which the worker reads (P2a).
#: A wake-up and a refill take a few tenths of a millisecond on a desktop, a few
#: milliseconds on a loaded small board.
MIN_MARGIN = 0.0003
MAX_MARGIN = 0.004
#: P2a: the turnaround assumed before any was measured (s).
FIRST_TURNAROUND = 0.00025
#: P2a: the margin over the turnaround. At 250000 baud the reply to the line before
#: the last comes about 0.7 ms before the wire runs dry: with 1.5 (was 2) the
#: worker caught it in most turns, 0.64 wake-ups a line instead of 0.77, with
#: the same link use (bench.streaming's Marlin ADVANCED_OK case, side by side).
MARGIN_FACTOR = 1.5
#: P3: bytes of disagreement a sample must show, how many samples in a row prove
#: the model wrong, and how often a wait is skipped to take a sample.
SLACK_BYTES = 32
EVIDENCE = 3
PROBE_EVERY = 16
#: P4: the reply line length assumed before any was read (Marlin's ADVANCED_OK
#: `ok N1234 P15 B3` and its newline).
FIRST_REPLY_BYTES = 16.0
#: P2 never waits longer than this (s), whatever the baud rate: emergencies and
#: polls are bounded by the loop's own deadlines anyway.
LONGEST_WAIT = 0.05
#: P5: a wait that woke before the reply was whole moves `lag` this part of the way
#: to what the read showed. One late answer (the firmware or its host busy for a
#: moment) must not set the wait of every line after it: waking too early costs one
#: short wait more (P4), waking too late costs link time on every line. Taking
#: each late answer whole, the lag rose to the slowest of the 15 answers between
#: two samples. Ping-pong at 250000 baud (bench.case, four runs each in turns):
#: link use 0.527-0.545 (segments) and 0.600-0.624 (long lines) that way,
#: 0.564-0.571 and 0.627-0.641 with a quarter, at the same CPU within the noise.
LAG_RISE = 0.25


class Pacer:
    """Tracks what the wire still has to send and when the worker should read."""

    def __init__(self, baud: int) -> None:
        #: Seconds a byte takes on the wire; 0 for no baud rate (never paced).
        self.byte_time = 10.0 / baud if baud > 0 else 0.0
        #: P2a: the worker's turnaround after a paced wake-up (s), moving average.
        self.turnaround = FIRST_TURNAROUND
        #: P4: bytes of a reply line, newline included (moving average).
        self.reply_bytes = FIRST_REPLY_BYTES
        #: P5: how long after a lone line has left the wire its reply starts (s).
        self.lag = 0.0
        self.reset()

    def reset(self) -> None:
        """A new connection: nothing on the wire, and the model is trusted again."""
        self.busy_until = 0.0
        #: False once P3 found the link faster than its baud rate.
        self.modelled = self.byte_time > 0
        self._evidence = 0
        self._waits = 0
        #: The paced wake-up the next write answers (None: the last read was not paced).
        self._due: float | None = None
        #: P4: bytes read since the last newline, and when the last read came.
        self._partial = 0
        self._read_at = 0.0
        #: P5: the end of the lone line on the wire and whether the read is made at
        #: once, while the next read teaches `lag`.
        self._lone: tuple[float, bool] | None = None

    @property
    def margin(self) -> float:
        """P2a: how long before the wire runs dry the worker reads."""
        return min(MAX_MARGIN, max(MIN_MARGIN, MARGIN_FACTOR * self.turnaround))

    def wrote(self, size: int, now: float) -> None:
        """P1: *size* bytes were handed to the port at *now*; P2a learns from it."""
        if self._due is not None:
            late = min(max(0.0, now - self._due), MAX_MARGIN)
            self.turnaround += 0.1 * (late - self.turnaround)
            self._due = None
        self.busy_until = max(now, self.busy_until) + size * self.byte_time

    def unsent(self, now: float) -> float:
        """Bytes written that the model says have not left the port yet."""
        if not self.byte_time:
            return 0.0
        return max(0.0, self.busy_until - now) / self.byte_time

    def received(self, data: bytes, now: float) -> None:
        """P4, P5: *data* was read at *now* (learns how long reply lines are, and
        after a lone line how long the firmware takes to answer)."""
        if self._lone is not None:
            sent, at_once = self._lone
            self._learn_lag(data, now, sent, at_once=at_once)
            self._lone = None
        self._read_at = now
        end = data.rfind(b"\n")
        if end < 0:
            self._partial += len(data)
            return
        lines = data.count(b"\n", 0, end + 1)
        mean = (self._partial + end + 1) / lines
        self.reply_bytes += 0.2 * (mean - self.reply_bytes)
        self._partial = len(data) - end - 1

    def sampling(self, now: float) -> bool:
        """P3: whether a read at *now* is a sample (`acknowledged` then learns from
        it); asked first, so the bytes in flight are counted only for samples."""
        return self.modelled and self.unsent(now) > SLACK_BYTES

    def acknowledged(self, bytes_in_flight: int, now: float) -> None:
        """P3: after replies were read, *bytes_in_flight* still wait for an answer."""
        unsent = self.unsent(now)
        if not self.modelled or unsent <= SLACK_BYTES:
            return
        if bytes_in_flight + SLACK_BYTES < unsent:
            self._evidence += 1
            self.modelled = self._evidence < EVIDENCE
        else:
            self._evidence = 0

    def read_at(self, now: float, lines_in_flight: int) -> float:
        """P2, P5: the time to read at (*now* when there is nothing to wait for)."""
        self._due = self._lone = None
        if not self.modelled or lines_in_flight < 1:
            return now
        lone = lines_in_flight == 1
        if lone:
            wake = self.busy_until + self.reply_bytes * self.byte_time + self.lag
        else:
            wake = self.busy_until - self.margin
        if wake > now:
            self._waits += 1
            if self._waits % PROBE_EVERY == 0:
                wake = now  # P3: this read is a sample
        if lone:
            self._lone = (self.busy_until, wake <= now)
        if wake <= now:
            return now
        due = min(wake, now + LONGEST_WAIT)
        if not lone:
            self._due = due  # P2a learns from the write that answers it
        return due

    def _learn_lag(
        self, data: bytes, now: float, sent: float, *, at_once: bool
    ) -> None:
        """P5: the first read after a lone line left the wire at *sent*."""
        lag = now - len(data) * self.byte_time - sent  # when its first byte came
        if lag > LONGEST_WAIT:
            return  # a long command, not the firmware's pace
        if b"\n" in data:  # whole: it came no later than that
            if at_once:
                self.lag = max(-LONGEST_WAIT, min(self.lag, lag))
        elif at_once:  # cut: it came just then
            self.lag = lag
        elif lag > self.lag:  # cut after a wait: later than thought, this once
            self.lag += LAG_RISE * (lag - self.lag)

    def rest_at(self, now: float) -> float | None:
        """P4: when the reply line the last read cut should be whole (None: no cut)."""
        if not self._partial or not self.modelled:
            return None
        missing = max(0.0, self.reply_bytes - self._partial)
        return min(self._read_at + (missing + 0.5) * self.byte_time, now + LONGEST_WAIT)
