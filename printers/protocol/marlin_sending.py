"""MarlinProtocol's sending: framing (F1-F4) and the window (W1-W3), a mixin.

What goes out and when: `offer` (the stream host's one call a line), `send`,
`can_send`, emergencies, and the pump that moves lines to the wire. The rules are in
marlin.py; the lines and their byte budget live in marlin_window.LineWindow.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from printers.protocol.checksum import has_own_number
from printers.protocol.errors import CommandRejected, LocalProtocolError
from printers.protocol.events import Sent
from printers.protocol.marlin_window import Line, m110_line, new_line

if TYPE_CHECKING:
    from printers.protocol.marlin import MarlinProtocol

__all__ = ["Sending"]


class Sending:
    """Framing and the window: the sending half of MarlinProtocol."""

    def can_send(self: MarlinProtocol, text: str) -> bool:
        """True when *text* may be queued now without breaking the window (W1-W3)."""
        window = self._window
        if window.queued or window.rewinding:
            return False
        live = window.live
        if live and len(live) >= self._max_lines():
            return False  # W2 whatever the line (room_for), so it is not framed
        line = self._line_for(text.strip())
        window.frame(line)
        return self._fits(line)

    def _line_for(self: MarlinProtocol, text: str) -> Line:
        """The Line for *text*: the one the last offer (or can_send) built when it is
        the same command (offered again each turn while the window has no room for
        it), so it is framed once."""
        line = self._asked
        numbered = self._numbering()
        if (
            line is None
            or line.text != text
            or line.numbered != numbered
            or line.m110 is not None
        ):
            line = self._asked = new_line(text, None, numbered=numbered)
        return line

    def _fits(self: MarlinProtocol, line: Line) -> bool:
        """W2, W3: room for *line*, framed (or for the M110 that must go first, F2)."""
        window = self._window
        if line.numbered and window.need_m110:
            line = m110_line(0, None)
            window.frame(line)
        return window.room_for(line, self._max_lines())

    def send(
        self: MarlinProtocol, text: str, now: float, *, tag: object = None
    ) -> None:
        """Queue one command; Ack(tag) follows its ok. See F1-F4 for framing."""
        if self.offer(text, now, tag=tag):  # CommandRejected for a bad line
            return
        if self.in_flight:
            raise LocalProtocolError(f"window full: cannot send {text.strip()!r} now")
        # Nothing in flight and no room all the same: a drain (R1) holds the wire.
        # offer() got past its early answers then, so the line is its last one.
        line = self._asked
        assert line is not None
        self._asked = None  # the line is the window's now: never handed out again
        self._window.enqueue(line)
        self._pump()

    def offer(
        self: MarlinProtocol, text: str, now: float, *, tag: object = None
    ) -> bool:
        """`send` when `can_send` would say yes, framing the line once; False (the
        line left out) when the window has no room for it now."""
        window = self._window
        window.advance(now)
        if window.queued or window.rewinding:
            return False
        live = window.live
        most = 1
        if live:
            most = self._max_lines()
            if len(live) >= most:
                return False  # W2 whatever the line (room_for), so it is not framed
        line = self._line_for(_validate(text))
        line.tag = tag
        if line.m110 is not None:
            line.internal = tag is None  # as m110_line makes it
        window.frame(line)
        if len(line.wire) > self._max_length:
            self._asked = None
            raise CommandRejected(
                f"line {line.wire!r} is {len(line.wire)} characters on the wire; the "
                f"firmware takes at most {self._max_length} and truncates the rest"
            )
        if line.numbered and window.need_m110:
            if not self._fits(line):
                return False
            self._asked = None  # the line is the window's now: never handed out again
            window.enqueue(line)  # behind the M110 that starts numbering (F2)
            self._pump()
            return True
        if not window.room_for(line, most):  # _fits without an M110 owed
            return False
        self._asked = None  # the line is the window's now: never handed out again
        window.go_live(line)  # what enqueue() and the pump would do, at once
        return True

    def send_emergency(self: MarlinProtocol, text: str, now: float) -> None:
        """Write *text* unnumbered ahead of everything unwritten, ignoring the window."""
        self._window.advance(now)
        self._window.add_emergency(_validate(text))

    def reset_line_numbers(self: MarlinProtocol, now: float) -> None:
        """Queue `N0 M110 N0`; the next numbered line is N1."""
        self._window.advance(now)
        self._window.enqueue(m110_line(0, None))
        self._pump()

    def data_to_send(self: MarlinProtocol) -> bytes:
        """All pending wire bytes (emergency lines first); emits Sent for each line."""
        self._pump()
        window = self._window
        if window.outbox:
            self._recovery.awaiting_ok = False  # R1: the hold is over, no ok came
        elif not window.urgent:
            return b""
        lines = window.take_unwritten()
        events = self._events
        for line in lines:
            events.append(Sent(line.wire, line.number, line.resend))
        self.lines_sent += len(lines)
        return "".join([f"{line.wire}\n" for line in lines]).encode("ascii")

    def _numbering(self: MarlinProtocol) -> bool:
        """F1: whether a command sent now is numbered."""
        return (
            self._checksums == "always"
            or (self._checksums == "printing" and self.printing)
            or self.writing_file
        )

    def _max_lines(self: MarlinProtocol) -> int:
        """W2: how many lines may be live at once in the flow mode in force
        (`flow_mode`, spelled out: this is asked several times a line)."""
        flow = self._flow
        if flow == "ping_pong" or not (self._advanced or flow == "buffered"):
            return 1
        if self._recovery.recovering:
            return 1 + self._recovery.settled_live()  # W4
        return self._max_b + 1 if self._advanced else self._bufsize

    def _pump(self: MarlinProtocol) -> None:
        # Asked twice a line; a stream's lines go live in offer(), so the window
        # mostly has nothing to move, and the flow limit is not worked out then.
        if self._window.has_lines_to_move:
            self._window.pump(self._max_lines())


def _validate(text: str) -> str:
    stripped = text.strip()
    if not stripped:
        raise CommandRejected(f"empty command {text!r}: there is nothing to send")
    if has_own_number(stripped):
        # `N7 M110 N500*127` framed again would set the firmware's line number
        # behind the host's back: every later line would be out of step.
        raise CommandRejected(
            f"{stripped[:30]!r} carries its own line number: printhost numbers the "
            "lines it sends (to set the number, send M110 N<n>)"
        )
    if stripped.isascii() and stripped.isprintable():  # " " to "~" only
        return stripped
    for char in stripped:
        if not " " <= char <= "~":
            raise CommandRejected(
                f"command {stripped!r} holds {char!r}: only printable ASCII can be sent"
            )
    return stripped
