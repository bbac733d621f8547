"""GRBL 1.1 as a sans-IO link: character counting, realtime bytes, status polls."""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

from printers.protocol.errors import LocalProtocolError
from printers.protocol.events import (
    Ack,
    CommandFailed,
    FirmwareInfo,
    FirmwareReset,
    LinkFailed,
    Received,
    Sent,
    StatusReport,
)
from printers.protocol.grbl_codes import REALTIME_COMMANDS
from printers.protocol.grbl_events import BuildOptions, CheckMode
from printers.protocol.grbl_lines import Line, check_settings
from printers.protocol.grbl_responses import Answer, parse_response
from printers.protocol.grbl_sending import Sending

if TYPE_CHECKING:
    from printers.protocol.events import Event

__all__ = ["GrblProtocol"]

# Rules of the GRBL link; everything that changes its state lives in this file.
#
#  on                    | when                                | then
#  ----------------------+-------------------------------------+------------------------
#  send(line)            | counted bytes + len+1 <= rx_buffer  | queued, bytes counted
#  send(EEPROM write)    | nothing in flight, and a report     | goes alone (ping-pong)
#                        | read since says Idle/Alarm/Check    | (`?` polled meanwhile)
#  send(anything)        | an EEPROM write in flight           | refused until answered
#  send(anything)        | `\x18` sent, no banner yet          | refused: GRBL restarts
#  send(bad line)        | always                              | CommandRejected
#  ok                    | a line in flight                    | Ack(oldest tag)
#  error:N               | a line in flight                    | CommandFailed(oldest)
#  ok / error:N          | nothing in flight                   | Received only (stale)
#  <State|...>           | always                              | StatusReport; progress
#                        |                                     | if State is working
#  [OPT:..,blocks,rx]    | always                              | BuildOptions; RX budget
#                        |                                     | becomes rx - 1
#  [MSG:Enabled]/Disabled| always                              | CheckMode; check_mode
#  Grbl <ver> banner     | always                              | FirmwareReset, abandon
#  ALARM:N, [...], other | always                              | its event, no answer
#  send_emergency(byte)  | byte is a realtime command          | goes first, uncounted
#  send_emergency(\x18)  | always                              | unwritten lines drop,
#                        |                                     | nothing until banner
#  data_to_send()        | poll due, no `?` pending for < 1 s  | `?` first, uncounted
#                        | (due every 0.1 s while an EEPROM    |
#                        | write waits for Idle, polls or not) |
#  handle_timeout()      | in flight, progress + ack_timeout   | LinkFailed, once per
#                        | (+ oldest line's G4 dwell) passed   | stall
#  handle_timeout()      | `\x18` sent, ack_timeout passed     | LinkFailed, unblocked
#
# Every received line yields Received(text, kind) before its meaning. GRBL executes
# lines in order and answers each exactly once, so an answer is the oldest line's.
# Its 128-byte RX ring drops what overflows, hence the counting; an EEPROM write
# turns its RX interrupt off, hence the ping-pong; and GRBL refuses `$x=` (error:8)
# or stalls the planner for G10 L2/G28.1 while it moves, hence the wait for Idle.

#: States in which GRBL may hold back `ok` for a long time: the planner is full.
_WORKING_STATES = frozenset({"Run", "Jog", "Home", "Hold", "Door", "Check"})
#: GRBL ignores a `?` sent before the previous report went out; ask again after this.
_POLL_RETRY = 1.0
#: States in which nothing moves: an EEPROM write may go (GRBL takes `$x=` in Alarm).
_SETTLED_STATES = frozenset({"Idle", "Alarm", "Check"})
#: Seconds between `?` polls while an EEPROM write waits for the machine to settle.
_SETTLE_POLL = 0.1
#: A "line" this long without a newline is noise; hand it over rather than grow forever.
_MAX_LINE_BYTES = 1024
_SOFT_RESET = "\x18"


class GrblProtocol(Sending):
    """The GRBL side of LinkProtocol: bytes and `now` in, bytes and events out.

    *rx_buffer*: bytes of unanswered lines GRBL can hold (its ring keeps 128).
    *max_line_length*: GRBL's line buffer less the newline. *ack_timeout*: seconds
    without an answer or motion before LinkFailed. *status_interval*: seconds
    between `?` polls, None for none. *compact*: strip spaces from G-code lines.
    """

    def __init__(
        self,
        *,
        rx_buffer: int = 127,
        max_line_length: int = 79,
        ack_timeout: float = 10.0,
        status_interval: float | None = 0.2,
        compact: bool = True,
    ) -> None:
        check_settings(rx_buffer, max_line_length, ack_timeout, status_interval)
        self.rx_buffer = rx_buffer
        self.max_line_length = max_line_length
        self.ack_timeout = ack_timeout
        self.status_interval = status_interval
        self.compact = compact
        #: Part of the LinkProtocol contract; GRBL streams the same either way.
        self.printing = False
        #: No file writing on GRBL; kept for the LinkProtocol contract.
        self.writing_file = False
        #: No line numbers to check: every line brings its own ok or error.
        self.closing_sync: str | None = None
        #: Command lines written so far (not counting realtime bytes or polls).
        self.lines_sent = 0
        #: Command lines answered (ok or error:N) so far.
        self.lines_acked = 0
        #: Round trip write -> answer (s), a moving average (link statistics).
        self.rtt = 0.0
        #: The latest status report, or None before the first.
        self.last_status: StatusReport | None = None
        #: `$C` check mode is on: lines are parsed, nothing moves.
        self.check_mode = False
        #: The last `[OPT:...]` read (from `$I`), or None.
        self.build_options: BuildOptions | None = None
        self._version = ""
        #: A report read after the last line was answered said nothing moves.
        self._settled = False
        #: An EEPROM write waits for that report: poll for it.
        self._want_settled = False
        #: Hold EEPROM writes until a report says Idle (off for a file: nothing moves).
        self.wait_for_idle = True
        #: When the oldest `?` still without any report went out.
        self._unreported_since: float | None = None
        self._events: deque[Event] = deque()
        #: The events not taken yet, oldest first (`next_event` pops them).
        self.events = self._events
        self._inbox = bytearray()
        self._outbox: deque[Line] = deque()  # accepted by send(), not yet written
        self._waiting: deque[Line] = deque()  # written, not yet answered
        self._written_at: deque[float] = deque()  # when each waiting line was written
        #: The last text prepared and what GRBL gets of it (wire text, EEPROM write,
        #: dwell): a line offered again while it does not fit is prepared once.
        self._prepared: tuple[str | None, str, bool, float] = (None, "", False, 0.0)
        self._realtime: list[tuple[bytes, str]] = []
        self._now: float | None = None
        self._progress_at = 0.0
        self._stall_reported = False
        self._reset_sent_at: float | None = None
        self._last_poll_at: float | None = None
        self._poll_pending_since: float | None = None

    # -- sending (what fits GRBL's buffer: grbl_sending.py) ------------------------

    def send_emergency(self, text: str, now: float) -> None:
        """Queue a realtime byte ahead of everything not yet written; never counted."""
        self._now = now
        name = REALTIME_COMMANDS.get(text)
        if name is None:
            raise LocalProtocolError(
                f"{text!r} is not a GRBL realtime command; send() takes command lines"
            )
        if text == "?":
            self._poll_pending_since = now
        elif text == _SOFT_RESET:
            # Lines written after the reset byte race GRBL's buffer flush: drop them,
            # and send nothing until the banner says GRBL is listening again.
            self._outbox.clear()
            self._reset_sent_at = now
        shown = text if text.isprintable() and text.isascii() else f"0x{ord(text):02x}"
        self._realtime.append((text.encode("latin-1"), f"<{shown} {name}>"))

    def reset_line_numbers(self, now: float) -> None:
        """GRBL has no line numbers: nothing to do."""
        self._now = now

    def data_to_send(self) -> bytes:
        """Realtime bytes, then a due `?` poll, then the queued lines, in one write."""
        out = bytearray()
        for raw, shown in self._realtime:
            out += raw
            self._events.append(Sent(shown))
        self._realtime.clear()
        if self._poll_due():
            out += b"?"
            self._last_poll_at = self._poll_pending_since = self._now
            if self._unreported_since is None:
                self._unreported_since = self._now
        while self._outbox:
            line = self._outbox.popleft()
            out += line.text.encode("ascii") + b"\n"
            self._events.append(Sent(line.text))
            self._settled = False
            self._waiting.append(line)
            self._written_at.append(self._now or 0.0)
            self.lines_sent += 1
        return bytes(out)

    def abandon(self) -> None:
        """Forget every line queued or in flight; realtime bytes still go out."""
        self._outbox.clear()
        self._waiting.clear()
        self._written_at.clear()
        self._want_settled = False
        self._unreported_since = None
        self._stall_reported = False

    @property
    def in_flight(self) -> int:
        """Lines accepted by send() and not yet answered."""
        return len(self._outbox) + len(self._waiting)

    @property
    def bytes_in_flight(self) -> int:
        """Bytes of lines written and not yet answered: what fills GRBL's RX buffer."""
        return sum(line.size for line in self._waiting)

    # -- receiving -----------------------------------------------------------------

    def receive_data(self, data: bytes, now: float) -> None:
        """Feed bytes from GRBL; b"" means nothing arrived. Partial lines wait."""
        self._now = now
        self._inbox += data
        while (end := self._inbox.find(b"\n")) >= 0:
            raw = bytes(self._inbox[:end])
            del self._inbox[: end + 1]
            self._read_line(raw, now)
        if len(self._inbox) > _MAX_LINE_BYTES:
            raw = bytes(self._inbox)
            self._inbox.clear()
            self._read_line(raw, now)

    def next_event(self) -> Event | None:
        """The next event, or None when more data is needed."""
        return self._events.popleft() if self._events else None

    # -- time ----------------------------------------------------------------------

    def next_deadline(self) -> float | None:
        """The earliest of: the ack deadline, the reset deadline, the next poll."""
        deadlines = [self._next_poll_at()]
        if self._reset_sent_at is not None:
            deadlines.append(self._reset_sent_at + self.ack_timeout)
        elif self.in_flight and not self._stall_reported:
            deadlines.append(self._ack_deadline())
        elif self._report_deadline() is not None and not self._stall_reported:
            deadlines.append(self._report_deadline())
        return min((d for d in deadlines if d is not None), default=None)

    def handle_timeout(self, now: float) -> None:
        """Report a stalled stream or a reset with no banner (polls: data_to_send)."""
        self._now = now
        if self._reset_sent_at is not None:
            if now >= self._reset_sent_at + self.ack_timeout:
                self._reset_sent_at = None
                self._stall_reported = True  # one failure is enough to report
                self._events.append(
                    LinkFailed(
                        f"GRBL did not restart within {self.ack_timeout:g} s of a "
                        "soft reset (no welcome banner)"
                    )
                )
            return
        if self.in_flight and not self._stall_reported and now >= self._ack_deadline():
            self._stall_reported = True
            self._events.append(LinkFailed(self._stall_message()))
        report_deadline = self._report_deadline()
        if report_deadline is not None and not self._stall_reported:
            self._report_missing(now, report_deadline)

    def _report_missing(self, now: float, deadline: float) -> None:
        if now >= deadline:
            self._stall_reported = True
            self._events.append(
                LinkFailed(
                    f"GRBL answered no status poll within {self.ack_timeout:g} s "
                    "while an EEPROM write waited for it to report Idle"
                )
            )

    def _report_deadline(self) -> float | None:
        """While an EEPROM write waits for a report: when missing reports fail the link."""
        if not self._want_settled or self._unreported_since is None:
            return None
        return self._unreported_since + self.ack_timeout

    # -- internals -----------------------------------------------------------------

    def _read_line(self, raw: bytes, now: float) -> None:
        text = raw.decode("utf-8", errors="replace").strip()
        if not text:
            return
        response = parse_response(text)
        self._events.append(Received(text, response.kind))
        meaning = response.meaning
        if isinstance(meaning, Answer):
            self._answer(meaning, now)
            return
        if isinstance(meaning, StatusReport):
            self._status(meaning, now)
        elif isinstance(meaning, FirmwareReset):
            self.abandon()
            self._reset_sent_at = None
            self._poll_pending_since = None
            self._settled = self.check_mode = False
        elif isinstance(meaning, CheckMode):
            self.check_mode = meaning.enabled
        elif isinstance(meaning, BuildOptions):
            self._adopt(meaning)
        elif isinstance(meaning, FirmwareInfo):
            meaning = self._identify(meaning)
        self._events.append(meaning)

    def _adopt(self, options: BuildOptions) -> None:
        """Count against the RX buffer GRBL reports (its ring keeps one byte free)."""
        self.build_options = options
        if options.rx_buffer is None or options.rx_buffer < 2:
            return
        self.rx_buffer = options.rx_buffer - 1
        # A tiny buffer shortens the longest line, so send() says why it cannot go.
        self.max_line_length = min(self.max_line_length, self.rx_buffer - 1)

    def _identify(self, info: FirmwareInfo) -> FirmwareInfo:
        """`[VER:1.1f...]` then grblHAL's `[FIRMWARE:grblHAL]`: "grblHAL 1.1f..."."""
        if "VER" in info.fields:
            self._version = info.fields["VER"]
            return info
        if "FIRMWARE" in info.fields and self._version:
            fields = {**info.fields, "VER": self._version}
            return FirmwareInfo(f"{info.name} {self._version}", fields)
        return info

    def _answer(self, answer: Answer, now: float) -> None:
        if not self._waiting:
            return  # the answer to a line abandoned since: nothing waits for it
        line = self._waiting.popleft()
        written = self._written_at.popleft()
        self.lines_acked += 1
        elapsed = min(max(0.0, now - written), 1.0)
        self.rtt = (
            elapsed if self.lines_acked == 1 else self.rtt + 0.2 * (elapsed - self.rtt)
        )
        self._progress_at = now
        self._stall_reported = False
        if answer.failed:
            self._events.append(CommandFailed(line.tag, answer.message, answer.code))
        else:
            self._events.append(Ack(line.tag))

    def _status(self, report: StatusReport, now: float) -> None:
        self.last_status = report
        self._poll_pending_since = self._unreported_since = None
        self._stall_reported = self._stall_reported and bool(self.in_flight)
        state = report.state.partition(":")[0]
        self.check_mode = state == "Check"
        if not self.in_flight:
            # GRBL writes in order: a report read after the last answer is newer.
            self._settled = state in _SETTLED_STATES
            if self._settled:
                self._want_settled = False
        if report.state.partition(":")[0] in _WORKING_STATES:
            # ok is held back while the planner is full; motion proves GRBL is alive.
            self._progress_at = now
            self._stall_reported = False

    def _next_poll_at(self) -> float | None:
        interval = self.status_interval
        if self._want_settled and not self._settled:
            interval = min(interval or _SETTLE_POLL, _SETTLE_POLL)
        if interval is None or self._now is None:
            return None
        last = self._last_poll_at
        due = self._now if last is None else last + interval
        if self._poll_pending_since is not None:
            due = max(due, self._poll_pending_since + _POLL_RETRY)
        return due

    def _poll_due(self) -> bool:
        due = self._next_poll_at()
        return due is not None and self._now is not None and self._now >= due

    def _oldest(self) -> Line:
        return self._waiting[0] if self._waiting else self._outbox[0]

    def _ack_deadline(self) -> float:
        return self._progress_at + self.ack_timeout + self._oldest().dwell

    def _stall_message(self) -> str:
        return (
            f"GRBL did not answer '{self._oldest().text}' within "
            f"{self.ack_timeout:g} s and reported no motion; GRBL never drops a line "
            "it took, so the stream cannot be trusted"
        )
