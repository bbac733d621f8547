"""Marlin host protocol, sans-IO: numbered lines, a byte/line window, resends, timeouts."""

# Rules of MarlinProtocol. Everything that changes the sender's state is listed here;
# the code below only carries them out (h11's _state.py habit).
#
# A command is *queued* (send), then *live* (charged to the window, written by
# data_to_send, waiting for its ok), then acknowledged. A resend makes live lines
# *dead*: they leave the ack queue, but their bytes stay charged until the drain delay
# has passed. in_flight = live + queued + lines waiting to be re-sent.
#
# Framing
#   F1  A line is numbered (`N<n> <text>*<xor>`) when checksums == "always", or
#       == "printing" and self.printing, or when it is an M110 (its own N sets n).
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
#
# Replies (each line emits Received(text, kind) before its meaning)
#   reply                         | effect                              | events
#   ok right after Resend/rs/skip | swallowed (it belongs to a bad line)| -
#   ok                            | acks the oldest live line (FIFO)    | Ack(tag)
#   ok N<n> P<p> B<b> / ok <n>    | acks live lines up to n; FIFO if n  | Ack(tag)...
#                                 | is unknown; P+B -> advanced_ok      |
#   ok T:...                      | as ok                               | Temperature..
#   Error: line number / checksum | remembered for the next Resend      | -
#   Resend: n / rs n              | R1-R6                               | ResendServed
#   skip n (Repetier)             | a duplicate (R3), or R6             | -
#   wait                          | T2                                  | -
#   busy:                         | progress, busy_timeout applies      | Busy
#   T:.. B:.. report              | progress if a long command is oldest| Temperature..
#   start                         | abandon() (F2 follows)              | FirmwareReset
#   kill()/thermal/`!!`/fatal:    | abandon()                           | FirmwareHalted
#   other Error:                  | -                                   | FirmwareError
#   //action:, FIRMWARE_NAME:,    | -                                   | ActionCommand,
#   Cap:, echo:, anything else    | -                                   | FirmwareInfo..
#
# Resends (Marlin flushes its RX ring on a bad line; every line already behind it
# then brings another Error + Resend for the same n, or nothing if it was flushed)
#   R1  The ok right after Resend/rs/skip is swallowed; any other line ends the wait.
#   R2  A genuine request for n: live lines numbered >= n die, lines n.. go again
#       from the history before anything new, dup_budget = lines that died (plus
#       what was left if n was already the recovery's), dead bytes stay charged
#       for rx_buffer*10/baud + round trip (EWMA of send->ok).
#   R3  Same n as the recovery, after a line-number error, dup_budget > 0: a
#       leftover of a dead line, dup_budget -= 1. After a checksum error, for
#       another n, or with the budget spent: genuine (R2).
#   R4  n == the next number never sent: nothing to re-send; n becomes the
#       recovery's, keeping its budget. n beyond it, or before this numbering's
#       M110: LinkFailed.
#   R5  The same n genuinely requested more than max_resends times: LinkFailed.
#   R6  The first Resend m (or skip m-1) after a timeout proves lines < m arrived:
#       they are acknowledged, and the re-sent copies among them (each will bring
#       its own Resend m) become the dup_budget of m. Timeout recovery ends.
#   Acknowledging a line >= the recovery's n ends the recovery.
#
# Timeouts (next_deadline / handle_timeout)
#   T1  Deadline = last progress (ok, busy, wait, resend, temperature during a long
#       command) or the oldest live line's write, + busy_timeout if busy: came
#       since, else ack_timeout. Passed: timeouts += 1; more than max_timeouts in a
#       row -> LinkFailed. Oldest live numbered -> re-send from it (R2, starting
#       timeout recovery). Unnumbered, not printing -> its ok was lost, Ack it.
#       Unnumbered while printing -> LinkFailed (it cannot be retried safely).
#   T2  `wait` while the oldest live line went out more than two round trips ago
#       acts as T1 without counting; otherwise it is ignored.
#   T3  Any ok resets the row of timeouts.
#   T4  In timeout recovery, an ok while nothing is live and the M110 waits to go
#       again was the M110's late ok: it is not sent again.
#
# Emergency: send_emergency() writes ahead of everything unwritten, ignoring the
# window. M112 expects no ok; others (M108, M410, M876) become live internal lines.
# Sent(text, line_number, resend) is emitted by data_to_send(), when the bytes are
# handed over, never earlier. Every LinkFailed is followed by abandon().

from __future__ import annotations

import re
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

from printers.protocol.checksum import format_line
from printers.protocol.errors import CommandRejected, LocalProtocolError
from printers.protocol.events import (
    Ack,
    FirmwareMessage,
    FirmwareReset,
    LineKind,
    LinkFailed,
    Received,
    ResendServed,
    Sent,
)
from printers.protocol.history import LineHistory
from printers.protocol.marlin_responses import Reply, ReplyKind, parse_response

if TYPE_CHECKING:
    from collections.abc import Callable

    from printers.protocol.events import Event

__all__ = ["MarlinProtocol"]

_CHECKSUM_MODES = ("always", "never", "printing")
_FLOW_MODES = ("auto", "ping_pong", "buffered")
_LONG_RUNNING = frozenset(
    {"M109", "M190", "M191", "M303", "G28", "G29", "M400", "G4", "M0", "M1", "M600"}
)
_NEWLINES = re.compile(rb"\r\n|\r|\n")
_M110 = re.compile(r"M110(?:\s+N(-?\d+))?\b", re.IGNORECASE)
_MAX_PARTIAL = 4096
_RTT_START = 0.05
_RTT_CAP = 1.0


@dataclass(eq=False, slots=True)
class _Line:
    """One command on its way; compared by identity."""

    text: str
    tag: object = None
    internal: bool = False
    numbered: bool = False
    #: The line number an M110 sets (its own N), None for other commands.
    m110: int | None = None
    wire: str = ""
    number: int | None = None
    resend: bool = False
    sent_at: float | None = None

    @property
    def cost(self) -> int:
        return len(self.wire) + 1

    @property
    def word(self) -> str:
        return self.text.split(None, 1)[0].upper()


class MarlinProtocol:
    """The Marlin side of the LinkProtocol contract (see printers.protocol.link)."""

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
        self._checksums, self._flow, self._baud = checksums, flow, baud
        self._rx_buffer, self._bufsize = rx_buffer, bufsize
        self._max_length, self._max_resends = max_line_length, max_resends
        self._ack_timeout, self._busy_timeout = ack_timeout, busy_timeout
        self._max_timeouts = max_timeouts
        #: True while a job is streaming (checksums="printing" numbers lines then).
        self.printing = False
        #: Statistics: genuine resend requests served, lines written, ack timeouts.
        self.resends = self.lines_sent = self.timeouts = 0
        self._events: deque[Event] = deque()
        self._rx = b""
        self._clock = 0.0
        self._history = LineHistory()
        self._advanced, self._max_b, self._rtt = False, 0, _RTT_START
        self._live: deque[_Line] = deque()
        self._outbox: deque[_Line] = deque()
        self._urgent: list[_Line] = []
        self._queued: deque[_Line] = deque()
        self._previous: Reply | None = None
        self._next_n = 0
        self.abandon()

    # -- read-only state -------------------------------------------------------------

    @property
    def in_flight(self) -> int:
        """Commands sent (or queued to go) and not yet answered."""
        return (
            len(self._live) + len(self._queued) + self._rewind_end - self._rewind_next
        )

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
        return sum(line.cost for line in self._live) + self._dead_bytes

    # -- the LinkProtocol contract ---------------------------------------------------

    def can_send(self, text: str) -> bool:
        """True when *text* may be queued now without breaking the window (W1-W3)."""
        if self._queued or self._rewind_next < self._rewind_end or self._m110_live():
            return False
        line = self._new_line(text.strip(), None)
        if line.numbered and self._need_m110:
            line = self._new_m110(0, None)
        self._frame(line)
        return self._room_for(line)

    def send(self, text: str, now: float, *, tag: object = None) -> None:
        """Queue one command; Ack(tag) follows its ok. See F1-F4 for framing."""
        self._advance(now)
        line = self._new_line(_validate(text), tag)
        self._frame(line)
        if len(line.wire) > self._max_length:
            raise CommandRejected(
                f"line {line.wire!r} is {len(line.wire)} characters on the wire; the "
                f"firmware takes at most {self._max_length} and truncates the rest"
            )
        if self.in_flight and not self.can_send(line.text):
            raise LocalProtocolError(f"window full: cannot send {line.text!r} now")
        if line.numbered and self._need_m110 and line.m110 is None:
            self._queued.append(self._new_m110(0, None))
        self._need_m110 = self._need_m110 and not line.numbered
        self._queued.append(line)
        self._pump()

    def send_emergency(self, text: str, now: float) -> None:
        """Write *text* unnumbered ahead of everything unwritten, ignoring the window."""
        self._advance(now)
        line = _Line(_validate(text), internal=True)
        line.wire = line.text
        self._urgent.append(line)
        if line.word != "M112":
            self._live.append(line)

    def reset_line_numbers(self, now: float) -> None:
        """Queue `N0 M110 N0`; the next numbered line is N1."""
        self._advance(now)
        self._queued.append(self._new_m110(0, None))
        self._need_m110 = False
        self._pump()

    def receive_data(self, data: bytes, now: float) -> None:
        """Feed firmware bytes; b"" only means nothing arrived (the clock still moves)."""
        self._advance(now)
        if data:
            lines = _NEWLINES.split(self._rx + data)
            self._rx = lines.pop()
            if len(self._rx) > _MAX_PARTIAL:
                lines.append(self._rx)
                self._rx = b""
            for raw in lines:
                if raw.strip():
                    self._handle_line(raw)
        self._pump()

    def next_event(self) -> Event | None:
        """The next event, or None when more data is needed."""
        return self._events.popleft() if self._events else None

    def data_to_send(self) -> bytes:
        """All pending wire bytes (emergency lines first); emits Sent for each line."""
        self._pump()
        lines = [*self._urgent, *self._outbox]
        self._urgent.clear()
        self._outbox.clear()
        for line in lines:
            line.sent_at = self._clock
            self._events.append(Sent(line.wire, line.number, line.resend))
        self.lines_sent += len(lines)
        return "".join(f"{line.wire}\n" for line in lines).encode("ascii")

    def next_deadline(self) -> float | None:
        """The ack deadline (T1) or the end of a resend drain, whichever is first."""
        deadlines = [
            d for d in (self._drain_until, self._ack_deadline()) if d is not None
        ]
        return min(deadlines) if deadlines else None

    def handle_timeout(self, now: float) -> None:
        """End a finished drain; on a passed ack deadline apply T1."""
        self._advance(now)
        deadline = self._ack_deadline()
        if deadline is not None and now >= deadline:
            self._on_timeout(counted=True)
        self._pump()

    def abandon(self) -> None:
        """Forget everything queued, live, dead and in recovery; renumber with M110."""
        self._live.clear()
        self._outbox.clear()
        self._urgent.clear()
        self._queued.clear()
        self._rewind_next = self._rewind_end = 0
        self._rewind_tags: dict[int, _Line] = {}
        self._recovery_n: int | None = None
        self._dup_budget = self._repeats = self._consecutive_timeouts = 0
        self._timeout_recovery = self._await_resend_ok = self._busy_seen = False
        self._dead_bytes = 0
        self._drain_until: float | None = None
        self._last_progress = self._clock
        self._need_m110 = True

    # -- framing and the window ------------------------------------------------------

    def _new_line(self, text: str, tag: object) -> _Line:
        if match := _M110.match(text):
            return self._new_m110(int(match[1] or 0), tag)
        numbered = self._checksums == "always" or (
            self._checksums == "printing" and self.printing
        )
        return _Line(text, tag, numbered=numbered)

    def _new_m110(self, n: int, tag: object) -> _Line:
        return _Line(f"M110 N{n}", tag, internal=tag is None, numbered=True, m110=n)

    def _frame(self, line: _Line) -> None:
        """Fill in number and wire text, as the line would go out next."""
        if line.m110 is not None:
            line.number = line.m110
        elif line.numbered and not line.resend:
            line.number = self._projected_number(line)
        line.wire = format_line(line.number, line.text) if line.numbered else line.text

    def _projected_number(self, line: _Line) -> int:
        n = 1 if self._need_m110 else self._next_n
        for queued in self._queued:
            if queued is line:
                break
            if queued.m110 is not None:
                n = queued.m110 + 1
            elif queued.numbered:
                n += 1
        return n

    def _room_for(self, line: _Line) -> bool:
        if self._drain_until is not None or self._m110_live():
            return False
        if not self._live:
            return True
        if line.m110 is not None or self.flow_mode == "ping_pong":
            return False
        budget = self._max_b + 1 if self._advanced else self._bufsize
        return len(self._live) < budget and (
            self.bytes_in_flight + line.cost <= self._rx_buffer
        )

    def _m110_next(self) -> bool:
        """True when the M110 itself waits to be re-sent."""
        return self._rewind_next == self._history.first < self._rewind_end

    def _m110_live(self) -> bool:
        return any(line.m110 is not None for line in self._live)

    def _pump(self) -> None:
        """Move lines to re-send, then queued lines, to the wire while W2 allows."""
        while (line := self._peek()) is not None and self._room_for(line):
            if line.resend:
                self._rewind_next += 1
            else:
                self._queued.popleft()
                self._number(line)
            self._live.append(line)
            self._outbox.append(line)
        if self._rewind_next >= self._rewind_end:
            self._rewind_tags.clear()

    def _peek(self) -> _Line | None:
        if self._rewind_next < self._rewind_end:
            n = self._rewind_next
            old = self._rewind_tags.get(n)
            text = self._history.get(n)
            line = _Line(
                text, None, internal=True, numbered=True, number=n, resend=True
            )
            if old is not None:
                line.tag, line.internal, line.m110 = old.tag, old.internal, old.m110
            elif _M110.match(text):
                line.m110 = n
        elif self._queued:
            line = self._queued[0]
        else:
            return None
        self._frame(line)
        return line

    def _number(self, line: _Line) -> None:
        if line.number is None:
            return
        if line.m110 is not None:
            self._history.clear(line.number)
        self._history.append(line.number, line.text)
        self._next_n = line.number + 1

    # -- replies ---------------------------------------------------------------------

    def _handle_line(self, raw: bytes) -> None:
        try:
            reply = parse_response(raw.decode("utf-8").strip())
        except UnicodeDecodeError:
            text = raw.decode("utf-8", errors="replace").strip()
            reply = Reply(
                ReplyKind.OTHER, LineKind.RESPONSE, text, event=FirmwareMessage(text)
            )
        self._events.append(Received(reply.text, reply.line_kind))
        if reply.kind is not ReplyKind.OK:
            self._await_resend_ok = False
        self._HANDLERS.get(reply.kind, MarlinProtocol._on_information)(self, reply)
        self._previous = reply

    def _on_ok(self, reply: Reply) -> None:
        self._progress()
        self._consecutive_timeouts = 0
        self._advanced = self._advanced or reply.advanced
        if reply.event is not None:
            self._events.append(reply.event)
        if self._await_resend_ok:
            self._await_resend_ok = False
            return
        if reply.buffer_free is not None:
            self._max_b = max(self._max_b, reply.buffer_free)
        if self._live and (reply.number is None or not self._ack_through(reply.number)):
            if not self._is_stale(reply.number):
                self._acknowledge(self._live.popleft())
        elif not self._live and self._timeout_recovery and self._m110_next():
            self._ack_unsent_before(self._rewind_next + 1)  # T4: late, not lost

    def _on_resend(self, reply: Reply) -> None:
        self._progress()
        self._await_resend_ok = True
        n = reply.number
        if self._need_m110 or n is None:
            return  # nothing numbered since the last reset: not ours
        if self._m110_next():
            return  # F3: the M110 goes again anyway, this is a leftover
        m110 = next((line.number for line in self._live if line.m110 is not None), None)
        if m110 is not None:  # F3: about the M110 itself, whatever number it names
            self._genuine_resend(m110, self._context(reply))
            return
        copies = self._ack_received(n) if self._timeout_recovery else 0
        self._timeout_recovery = False
        if copies:
            self._recovery_n, self._dup_budget, self._repeats = n, copies - 1, 0
        elif self._is_duplicate(n):
            self._dup_budget -= 1
            return
        if n == self._next_n:
            self._recovery_n, self._repeats = n, 0
            return
        elif not self._history.first <= n < self._next_n:
            self._fail(
                f"cannot resend line {n}: only lines {self._history.first} to "
                f"{self._next_n - 1} were sent since the last M110 ({reply.text!r})"
            )
            return
        self._genuine_resend(n, self._context(reply))

    def _context(self, reply: Reply) -> str:
        """The error line that came with a Resend, for ResendServed's message."""
        previous = self._previous
        resend_errors = (ReplyKind.LINE_NUMBER_ERROR, ReplyKind.CHECKSUM_ERROR)
        return (
            previous.text if previous and previous.kind in resend_errors else reply.text
        )

    def _is_duplicate(self, n: int) -> bool:
        previous = self._previous.kind if self._previous else None
        return (
            n == self._recovery_n
            and previous is ReplyKind.LINE_NUMBER_ERROR
            and self._dup_budget > 0
        )

    def _on_skip(self, reply: Reply) -> None:
        self._progress()
        self._await_resend_ok = True
        if self._timeout_recovery and reply.number is not None:
            self._ack_received(reply.number + 1)
            self._timeout_recovery = False
        elif self._dup_budget > 0:
            self._dup_budget -= 1

    def _on_wait(self, reply: Reply) -> None:
        self._progress()
        sent_at = self._live[0].sent_at if self._live else None
        if sent_at is not None and self._clock - sent_at > 2 * self._rtt:
            self._on_timeout(counted=False)

    def _on_busy(self, reply: Reply) -> None:
        self._progress()
        self._busy_seen = True
        self._on_information(reply)

    def _on_temperature(self, reply: Reply) -> None:
        if self._live and self._live[0].word in _LONG_RUNNING:
            self._progress()
        self._on_information(reply)

    def _on_start(self, reply: Reply) -> None:
        self._events.append(FirmwareReset(reply.text))
        self.abandon()

    def _on_halt(self, reply: Reply) -> None:
        self._on_information(reply)
        self.abandon()

    def _on_information(self, reply: Reply) -> None:
        if reply.event is not None:
            self._events.append(reply.event)

    def _on_resend_error(self, reply: Reply) -> None:
        """Error lines of the resend flow mean nothing until their Resend comes."""

    _HANDLERS: ClassVar[dict[ReplyKind, Callable[[MarlinProtocol, Reply], None]]] = {
        ReplyKind.OK: _on_ok,
        ReplyKind.RESEND: _on_resend,
        ReplyKind.SKIP: _on_skip,
        ReplyKind.WAIT: _on_wait,
        ReplyKind.BUSY: _on_busy,
        ReplyKind.TEMPERATURE: _on_temperature,
        ReplyKind.START: _on_start,
        ReplyKind.HALT: _on_halt,
        ReplyKind.LINE_NUMBER_ERROR: _on_resend_error,
        ReplyKind.CHECKSUM_ERROR: _on_resend_error,
    }

    # -- acknowledgements, resends, timeouts -----------------------------------------

    def _acknowledge(self, line: _Line) -> None:
        if line.sent_at is not None:
            self._rtt += 0.2 * (min(self._clock - line.sent_at, _RTT_CAP) - self._rtt)
        self._busy_seen = self._timeout_recovery = False
        if not line.internal:
            self._events.append(Ack(line.tag))
        recovery = self._recovery_n
        if recovery is not None and line.number is not None and line.number >= recovery:
            self._end_recovery()

    def _is_stale(self, n: int | None) -> bool:
        """ok N<n> for a line acked already (a second copy of an M110): ignore it."""
        oldest = next(
            (line.number for line in self._live if line.number is not None), None
        )
        return (
            n is not None and oldest is not None and self._history.first <= n < oldest
        )

    def _ack_through(self, n: int) -> bool:
        """ok N<n>: ack live lines through line n; False when n is not live."""
        for index, line in enumerate(self._live):
            if line.number == n:
                for _ in range(index + 1):
                    self._acknowledge(self._live.popleft())
                return True
        return False

    def _ack_received(self, m: int) -> int:
        """R6: the firmware holds every line before m; returns re-sent copies acked."""
        last = -1
        for index, line in enumerate(self._live):
            if line.number is not None and line.number < m:
                last = index
        copies = 0
        for _ in range(last + 1):
            line = self._live.popleft()
            copies += line.resend and line.sent_at is not None
            self._acknowledge(line)
        self._ack_unsent_before(m)
        return copies

    def _ack_unsent_before(self, m: int) -> None:
        """Lines waiting to be re-sent that the firmware proved it has: skip, ack."""
        while self._rewind_next < min(m, self._rewind_end):
            old = self._rewind_tags.pop(self._rewind_next, None)
            if old is not None and not old.internal:
                self._events.append(Ack(old.tag))
            self._rewind_next += 1

    def _genuine_resend(self, n: int, message: str) -> None:
        self._repeats = self._repeats + 1 if n == self._recovery_n else 1
        if self._repeats > self._max_resends:
            self._fail(
                f"firmware keeps asking for line {n} ({self._repeats} times in a row): "
                "check the cable, its shielding and the baud rate"
            )
            return
        self.resends += 1
        self._rewind(n, message)

    def _rewind(self, n: int, message: str) -> None:
        """R2: lines >= n die and go again from the history, after a drain delay."""
        self._ack_unsent_before(n)
        dead = [
            line for line in self._live if line.number is not None and line.number >= n
        ]
        if dead:
            self._live = deque(line for line in self._live if line not in dead)
            self._outbox = deque(line for line in self._outbox if line not in dead)
            written = sum(line.cost for line in dead if line.sent_at is not None)
            if written:
                self._dead_bytes += written
                drain = self._rx_buffer * 10 / self._baud + self._rtt
                self._drain_until = max(self._drain_until or 0.0, self._clock + drain)
        tags = {k: v for k, v in self._rewind_tags.items() if k >= n}
        tags.update((line.number, line) for line in dead if line.number is not None)
        self._rewind_next, self._rewind_end, self._rewind_tags = n, self._next_n, tags
        same = n == self._recovery_n
        self._dup_budget = len(dead) + (self._dup_budget if same else 0)
        self._recovery_n = n
        self._events.append(ResendServed(n, message))

    def _end_recovery(self) -> None:
        self._recovery_n = None
        self._dup_budget = self._repeats = 0

    def _on_timeout(self, *, counted: bool) -> None:
        oldest = self._live[0]
        waited = self._clock - (oldest.sent_at or self._clock)
        if counted:
            self.timeouts += 1
            self._consecutive_timeouts += 1
            if self._consecutive_timeouts > self._max_timeouts:
                self._fail(
                    f"no answer to {oldest.wire!r} after {waited:.1f} s and "
                    f"{self._consecutive_timeouts} timeouts: is the printer alive?"
                )
                return
        self._progress()
        self._busy_seen = False
        if oldest.number is not None:
            if oldest.number != self._recovery_n:
                self._repeats = 0
            self._rewind(
                oldest.number, f"no answer to line {oldest.number} in {waited:.1f} s"
            )
            self._timeout_recovery = True
        elif not self.printing:
            self._acknowledge(self._live.popleft())
        else:
            self._fail(
                f"no answer to {oldest.wire!r} after {waited:.1f} s; an unnumbered "
                "line cannot be retried safely while printing"
            )

    def _ack_deadline(self) -> float | None:
        if not self._live or self._live[0].sent_at is None:
            return None
        base = max(self._last_progress, self._live[0].sent_at)
        return base + (self._busy_timeout if self._busy_seen else self._ack_timeout)

    def _progress(self) -> None:
        self._last_progress = self._clock

    def _advance(self, now: float) -> None:
        self._clock = now
        if self._drain_until is not None and now >= self._drain_until:
            self._drain_until = None
            self._dead_bytes = 0

    def _fail(self, message: str) -> None:
        self._events.append(LinkFailed(message))
        self.abandon()


def _validate(text: str) -> str:
    stripped = text.strip()
    if not stripped:
        raise CommandRejected(f"empty command {text!r}: there is nothing to send")
    for char in stripped:
        if not " " <= char <= "~":
            raise CommandRejected(
                f"command {stripped!r} holds {char!r}: only printable ASCII can be sent"
            )
    return stripped
