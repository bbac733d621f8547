"""Marlin host protocol, sans-IO: numbered lines, a byte/line window, resends, timeouts."""

# Rules of MarlinProtocol. Everything that changes the sender's state is listed here;
# the code below, marlin_sending.py, marlin_replies.py, marlin_window.py,
# marlin_recovery.py, marlin_deadlines.py, marlin_trust.py and marlin_probe.py only
# carry them out (h11's _state.py habit).
#
# A command is *queued* (send), then *live* (charged to the window, written by
# data_to_send, waiting for its ok), then acknowledged. A resend makes live lines
# *dead*: they leave the ack queue, but their bytes stay charged until the drain delay
# has passed. in_flight = live + queued + lines waiting to be re-sent.
#
# Framing
#   F1  A line is numbered (`N<n> <text>*<xor>`) when checksums == "always", or
#       == "printing" and self.printing, or while writing_file (a line garbled on
#       its way into a file on the SD card would never be noticed), or when it is
#       an M110 (its own N sets n).
#   F2  The first numbered line after construction, abandon() or `start` is preceded
#       by an automatic internal `N0 M110 N0` (tag None, never Acked).
#   F3  An M110 goes alone: only with nothing live, and nothing follows it before its
#       ok. A Resend while it is live is about the M110, whatever number it names
#       (Marlin may still count from an earlier session); a Resend while the M110
#       waits to go again is a leftover. Its second ok `ok N0` is stale, ignored.
#   F4  send() refuses (CommandRejected) empty text, characters outside printable
#       ASCII and wire lines longer than max_line_length (Marlin truncates them).
#
# Window (can_send, and the pump moving lines to the wire)
#   W1  Lines to re-send go first, then queued lines in order; can_send is False
#       while either exists, while an M110 is live, or while draining.
#   W2  ping_pong: one line live. buffered: lines < bufsize. advanced (ADVANCED_OK
#       seen, flow not "ping_pong"): lines < max(B)+1. Both windowed modes also keep
#       sum(len(wire)+1) of live and dead lines <= rx_buffer.
#   W3  With nothing live and nothing dead any one line may go (never deadlock).
#   W4  While a re-sent line waits for its ok, it is the only live line from the
#       requested one on: on a noisy line a whole window sent again is rarely whole.
#
# Replies (each line emits Received(text, kind) before its meaning)
#   reply                         | effect                              | events
#   ok after Resend/rs/skip       | swallowed (it belongs to a bad line)| -
#   ok                            | acks the oldest live line (FIFO)    | Ack(tag)
#   ok N<n> P<p> B<b> / ok <n>    | acks live lines up to n; FIFO if n  | Ack(tag)...
#                                 | is unknown; P+B -> advanced_ok      |
#   ok T:...                      | T5, else as ok                      | Temperature..
#   Error: line number / checksum | R1b, R8 (any firmware's wording,    | -
#   (also garbled or cut short)   | never fatal)                        |
#   Resend: n / rs n              | R1-R6                               | ResendServed
#   skip n (Repetier)             | a duplicate (R3), or R6             | -
#   wait                          | T2                                  | -
#   busy:                         | progress, busy_timeout applies      | Busy
#   busy: paused for user/input   | progress, no deadline until ok (T1a)| Busy
#   T:.. B:.. report              | progress if a long command is oldest| Temperature..
#   start (also after junk bytes) | abandon() (F2 follows)              | FirmwareReset
#   kill()/thermal/`!!`/fatal:    | abandon()                           | FirmwareHalted
#   other Error:                  | -                                   | FirmwareError
#   //action:, FIRMWARE_NAME:,    | -                                   | ActionCommand,
#   Cap:, echo:, anything else    | -                                   | FirmwareInfo..
#   Begin file list .. End file   | file names (`SKIP.GCO 12`), never   | Received
#   list (M20)                    | replies; an ok ends the list too    |
#
# Resends (Marlin flushes its RX ring on a bad line; every line already behind it
# then brings another Error + Resend for the same n, or nothing if it was flushed)
#   R1  The first ok after Resend/rs/skip is swallowed. Nothing is written for a
#       drain delay after a Resend (its ok comes first); writing a line after it
#       ends the wait (Smoothieware's `rs` and some Marlin 2.0 builds send no ok).
#   R1b A line error then ok (some firmware sends ok before Resend): the ok is held;
#       a Resend next proves it was the error's (dropped, no ok awaited after the
#       Resend); any other reply releases it as a line's ok.
#   R2  A genuine request for n: live lines numbered >= n die, lines n.. go again
#       from the history before anything new, dup_budget = lines that died behind
#       the refused one (plus
#       what was left if n was already the recovery's), dead bytes stay charged
#       for rx_buffer*10/baud + round trip (EWMA of send->ok).
#   R3  Same n as the recovery, after a line-number error, dup_budget > 0: a
#       leftover of a dead line, dup_budget -= 1. After a checksum error, for
#       another n, or with the budget spent: genuine (R2).
#   R4  n == the next number never sent: nothing to re-send; n becomes the
#       recovery's, keeping its budget.
#   R5  The same n genuinely requested more than max_resends times: LinkFailed.
#   R6  The first Resend m (or skip m-1) after a timeout proves lines < m arrived:
#       they are acknowledged, and the re-sent copies among them (each will bring
#       its own Resend m) become the dup_budget of m. Timeout recovery ends.
#   R7  A Resend for a line already acknowledged (below the oldest unacknowledged
#       line), when it names the first line after the M110 or lies more than
#       RESET_GAP lines back, means the firmware reset without a readable `start`
#       (a silent reset, boot noise): FirmwareReset, abandon(); nothing is
#       replayed. Lost oks only make the firmware ask for *later* lines; only
#       oks taken for the wrong line (R1 with the Error and Resend lost) make it
#       ask for earlier ones, one line per such ok (those are served). Believed
#       when it comes twice in a row, each time agreeing with its error line
#       (`Last Line: n-1`) if the firmware words its errors; else ignored.
#   R8  A line error with no Resend within ERROR_WAIT + 2 round trips (lost or
#       garbled, or none sent: Prusa's `No Line Number with checksum`): the
#       oldest live line goes again as after a timeout (R6 sorts out what the
#       firmware had), uncounted; with nothing live, the line after the one the
#       error names. A held ok (R1b) is dropped then.
#   R9  A Resend for a line never sent, one contradicting its error line, or one
#       that cannot be read (garbled) is line noise: ignored, its ok swallowed,
#       R8 still watching its error.
#   Acknowledging a line >= the recovery's n ends the recovery.
#
# Timeouts (next_deadline / handle_timeout)
#   T1  Deadline = last progress (ok, busy, wait, resend, temperature during a long
#       command) or the oldest live line's write, + busy_timeout if busy: came
#       since, else ack_timeout. Passed: timeouts += 1; more than max_timeouts in a
#       row -> LinkFailed. Oldest live numbered -> re-send from it (R2, starting
#       timeout recovery). Unnumbered, not printing -> its ok was lost, Ack it.
#       Unnumbered while printing -> LinkFailed (it cannot be retried safely).
#   T1a After `busy: paused for user` / `paused for input` (M600, M0, a host
#       prompt) there is no deadline and no probe: a person may take any time. The
#       next ok (or a busy: of another kind) brings normal timing back.
#   T2  `wait` while the oldest live line went out more than two round trips ago
#       acts as T1 without counting; otherwise it is ignored.
#   T3  Any ok resets the row of timeouts.
#   T4  In timeout recovery, an ok while nothing is live and the M110 waits to go
#       again was the M110's late ok: it is not sent again.
#   T5  `ok T:..` (the answer of an M105) acknowledges every live line up to the
#       newest live numbered M105: the firmware runs lines in order, so the oks of
#       the lines before it were lost.
#   T6  The oldest live numbered line's ok is PROBE_AFTER + 4 round trips late,
#       nothing long-running (G28, G29, M109, M190, M400, G4...) or busy: in the
#       way: a numbered M105 probe goes out beyond the window (during a re-send,
#       the next line to re-send instead), at most 3 live. Lost ok -> T5; lost or
#       cut line -> the probe brings its Resend. Nothing is sent twice. Off for
#       RepRapFirmware (FIRMWARE_NAME), which does not check the sequence, and
#       while writing_file (M28 writes every line it gets into the file).
#
# Replies merged by a lost line end are split first (`okok`, `Resend: 5ok`).
#
# Closing a job
#   S1  A job's last line is followed by closing_sync, a numbered M105, and the job
#       ends on its ok. A last line lost with its Error and Resend garbled leaves
#       only an ok, taken for the lost line's; nothing after it would ever name the
#       gap, but the sync's line-number error does (R7 serves it). None when lines
#       are not numbered or the firmware does not check the sequence (RepRapFirmware).
#
# Emergency: send_emergency() writes ahead of everything unwritten, ignoring the
# window. M112 expects no ok; others (M108, M410, M876) become live internal lines.
# Sent(text, line_number, resend) is emitted by data_to_send(), when the bytes are
# handed over, never earlier. Every LinkFailed is followed by abandon().

from __future__ import annotations

import re
from collections import deque
from typing import TYPE_CHECKING

from printers.protocol.events import (
    FirmwareReset,
    LinkFailed,
)
from printers.protocol.marlin_probe import PROBE, PROBE_AFTER
from printers.protocol.marlin_recovery import Recovery
from printers.protocol.marlin_replies import ReplyHandling
from printers.protocol.marlin_responses import (
    Reply,
    split_merged,
)
from printers.protocol.marlin_sending import Sending
from printers.protocol.marlin_window import Line, LineWindow

if TYPE_CHECKING:
    from printers.protocol.events import Event

__all__ = ["MarlinProtocol"]

_CHECKSUM_MODES = ("always", "never", "printing")
_FLOW_MODES = ("auto", "ping_pong", "buffered")
_NEWLINES = re.compile(rb"\r\n|\r|\n")
_MAX_PARTIAL = 4096


class MarlinProtocol(Sending, ReplyHandling):
    """The Marlin side of the LinkProtocol contract (see printers.protocol.link).

    Lines and the window live in a LineWindow (marlin_window), acknowledgements,
    resends and timeouts in a Recovery over it (marlin_recovery); framing and the
    window's rules are the Sending mixin's (marlin_sending), each reply's meaning
    ReplyHandling's (marlin_replies); this class reads replies, keeps the flow mode
    and the statistics.
    """

    def __init__(
        self,
        *,
        checksums: str = "printing",
        flow: str = "auto",
        rx_buffer: int = 127,
        bufsize: int = 4,
        max_line_length: int = 95,
        ack_timeout: float = 10.0,
        busy_timeout: float = 30.0,
        max_resends: int = 10,
        max_timeouts: int = 5,
        probe_after: float | None = PROBE_AFTER,
        baud: int = 115200,
    ) -> None:
        if checksums not in _CHECKSUM_MODES or flow not in _FLOW_MODES:
            raise ValueError(
                f"checksums must be one of {_CHECKSUM_MODES}, flow one of {_FLOW_MODES}"
            )
        if (
            min(rx_buffer, bufsize, max_line_length, max_resends) < 1
            or max_timeouts < 0
        ):
            raise ValueError(
                "buffer sizes and max_resends must be >= 1, max_timeouts >= 0"
            )
        if min(ack_timeout, busy_timeout, baud) <= 0:
            raise ValueError("ack_timeout, busy_timeout and baud must be > 0")
        self._checksums, self._flow = checksums, flow
        self._bufsize, self._max_length = bufsize, max_line_length
        #: True while a job is streaming (checksums="printing" numbers lines then).
        self.printing = False
        #: Statistics: lines written (resends and timeouts: see the properties).
        self.lines_sent = 0
        self._events: deque[Event] = deque()
        #: The events not taken yet, oldest first (`next_event` pops them).
        self.events = self._events
        self._rx = b""
        self._advanced, self._max_b = False, 0
        self._previous: Reply | None = None
        #: Between M20's `Begin file list` and its end: lines are file names.
        self._file_list = False
        #: The line can_send last built (see _line_for).
        self._asked: Line | None = None
        self._window = LineWindow(rx_buffer=rx_buffer, baud=baud)
        self._recovery = Recovery(
            self._window,
            self._events,
            self._fail,
            self._silent_reset,
            max_resends=max_resends,
            max_timeouts=max_timeouts,
            ack_timeout=ack_timeout,
            busy_timeout=busy_timeout,
            probe_after=probe_after,
        )

    # -- read-only state -------------------------------------------------------------

    @property
    def in_flight(self) -> int:
        """Commands sent (or queued to go) and not yet answered."""
        return self._window.in_flight

    @property
    def flow_mode(self) -> str:
        """The window in force: "ping_pong", "buffered" or "advanced"."""
        if self._flow == "ping_pong":
            return "ping_pong"
        if self._advanced:
            return "advanced"
        return "buffered" if self._flow == "buffered" else "ping_pong"

    @property
    def advanced_ok(self) -> bool:
        """True once an ADVANCED_OK reply (`ok N.. P.. B..`) has been seen."""
        return self._advanced

    @property
    def bytes_in_flight(self) -> int:
        """Bytes charged to the firmware's RX buffer: live lines plus draining dead ones."""
        return self._window.bytes_in_flight

    @property
    def closing_sync(self) -> str | None:
        """S1: the numbered line that closes a job, or None when it would prove nothing."""
        numbered = self._checksums == "always" or (
            self._checksums == "printing" and self.printing
        )
        prober = self._recovery.prober
        return PROBE if numbered and prober.probing and not self.writing_file else None

    @property
    def writing_file(self) -> bool:
        """True while the firmware writes every line into a file (M28 to its SD card):
        the protocol then sends nothing of its own (no probes, T6)."""
        return self._recovery.prober.writing_file

    @writing_file.setter
    def writing_file(self, value: bool) -> None:
        self._recovery.prober.writing_file = value

    @property
    def resends(self) -> int:
        """Statistics: genuine resend requests served."""
        return self._recovery.resends

    @property
    def probes(self) -> int:
        """Statistics: numbered M105 probes sent for late oks (T6)."""
        return self._recovery.prober.probes

    @property
    def timeouts(self) -> int:
        """Statistics: ack timeouts (T1)."""
        return self._recovery.timeouts

    @property
    def lines_acked(self) -> int:
        """Statistics: lines acknowledged (internal ones too)."""
        return self._recovery.acked

    @property
    def rtt(self) -> float:
        """Statistics: the round trip write -> ok (s), a moving average."""
        return self._recovery.rtt

    # -- the LinkProtocol contract ---------------------------------------------------

    def receive_data(self, data: bytes, now: float) -> None:
        """Feed firmware bytes; b"" only means nothing arrived (the clock still moves)."""
        self._window.advance(now)
        if data:
            lines = _NEWLINES.split(self._rx + data)
            self._rx = lines.pop()
            if len(self._rx) > _MAX_PARTIAL:
                lines.append(self._rx)
                self._rx = b""
            for raw in lines:
                # Undecodable bytes become U+FFFD: junk that only `start` may follow.
                text = raw.decode("utf-8", errors="replace").strip()
                if text.startswith("ok") and self._quick_ok(text):
                    continue
                for part in split_merged(text) if text else ():
                    self._handle_line(part)
        self._pump()

    def next_event(self) -> Event | None:
        """The next event, or None when more data is needed."""
        return self._events.popleft() if self._events else None

    def next_deadline(self) -> float | None:
        """The ack deadline (T1) or the end of a resend drain, whichever is first."""
        first = self._window.drain_until
        deadline = self._recovery.next_deadline()
        if deadline is not None and (first is None or deadline < first):
            return deadline
        return first

    def handle_timeout(self, now: float) -> None:
        """End a finished drain; on a passed ack deadline apply T1."""
        self._window.advance(now)
        recovery = self._recovery
        error_deadline = recovery.error_deadline()
        if error_deadline is not None and now >= error_deadline:
            recovery.error_timeout(printing=self.printing)
        deadline = recovery.deadline()
        if deadline is not None and now >= deadline:
            recovery.timeout(printing=self.printing)
        probe = recovery.probe_deadline()
        if probe is not None and now >= probe:
            recovery.prober.send()
        self._pump()

    def abandon(self) -> None:
        """Forget everything queued, live, dead and in recovery; renumber with M110."""
        self._window.clear()
        self._recovery.reset()

    # -- resets and failures -------------------------------------------------------

    def _silent_reset(self, banner: str) -> None:
        """R7: the firmware counts from zero again without having said so."""
        self._events.append(FirmwareReset(banner))
        self.abandon()

    def _fail(self, message: str) -> None:
        self._events.append(LinkFailed(message))
        self.abandon()
