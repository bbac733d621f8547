"""MarlinProtocol's window: queued, live, dead and re-sent lines and their byte budget."""

from __future__ import annotations

import re
from collections import deque
from dataclasses import dataclass, field

from printers.protocol.checksum import checksum
from printers.protocol.history import LineHistory

__all__ = ["Line", "LineWindow", "m110_line", "new_line"]

_M110 = re.compile(r"M110(?:\s+N(-?\d+))?\b", re.IGNORECASE)


@dataclass(eq=False, slots=True)
class Line:
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
    _word: str = field(default="", repr=False)

    @property
    def cost(self) -> int:
        return len(self.wire) + 1

    @property
    def word(self) -> str:
        """The command word, upper case (`G1`, `M105`): asked every turn of the
        loop of the oldest live line (T6), so worked out once."""
        if not self._word:
            self._word = self.text.split(None, 1)[0].upper()
        return self._word


def new_line(text: str, tag: object, *, numbered: bool) -> Line:
    """A command as given to send(); an M110 is numbered by its own N (F1)."""
    if text[:1] in "Mm" and (match := _M110.match(text)):
        return m110_line(int(match[1] or 0), tag)
    return Line(text, tag, numbered=numbered)


def m110_line(n: int, tag: object) -> Line:
    """`M110 N<n>`; internal (never Acked) when it has no tag."""
    return Line(f"M110 N{n}", tag, internal=tag is None, numbered=True, m110=n)


class LineWindow:
    """Where every line is between send() and its ok, and what the firmware holds.

    Lines are *queued*, then *live* (charged to the window, in `outbox` until
    written), then acknowledged; a rewind makes live lines *dead* and re-sends lines
    `rewind_next`..`rewind_end - 1` from the history (see the rules in marlin.py).
    """

    def __init__(self, *, rx_buffer: int, baud: int) -> None:
        self._rx_buffer, self._baud = rx_buffer, baud
        #: The protocol's clock: the `now` of the latest call.
        self.clock = 0.0
        #: Text of every numbered line since the last M110, to re-send from.
        self.history = LineHistory()
        #: The number the next new numbered line gets.
        self.next_n = 0
        self.live: deque[Line] = deque()
        self.outbox: deque[Line] = deque()
        self.urgent: list[Line] = []
        self.queued: deque[Line] = deque()
        #: The last command text checksummed, and its checksum: a line is framed
        #: several times on its way (can_send, send, the pump), its text once.
        self._checksummed: tuple[str, int] = ("", 0)
        self.clear()

    def clear(self) -> None:
        """Forget every queued, live, dead and re-sent line (F2 follows)."""
        self.live.clear()
        self.outbox.clear()
        self.urgent.clear()
        self.queued.clear()
        self.rewind_next = self.rewind_end = 0
        #: The dead lines to re-send, by number, for their tags.
        self.rewind_tags: dict[int, Line] = {}
        self.dead_bytes = 0
        self.drain_until: float | None = None
        self.need_m110 = True

    @property
    def in_flight(self) -> int:
        """Lines live, queued or waiting to be re-sent."""
        return len(self.live) + len(self.queued) + self.rewind_end - self.rewind_next

    @property
    def bytes_in_flight(self) -> int:
        """Bytes charged to the firmware's RX buffer: live lines plus dead ones."""
        return sum(line.cost for line in self.live) + self.dead_bytes

    @property
    def rewinding(self) -> bool:
        """True while lines wait to be re-sent."""
        return self.rewind_next < self.rewind_end

    def advance(self, now: float) -> None:
        """Move the clock; a finished drain frees the dead lines' bytes."""
        self.clock = now
        if self.drain_until is not None and now >= self.drain_until:
            self.drain_until = None
            self.dead_bytes = 0

    def enqueue(self, line: Line) -> None:
        """Queue *line*, behind an automatic `M110 N0` if it starts numbering (F2)."""
        if line.numbered and self.need_m110 and line.m110 is None:
            self.queued.append(m110_line(0, None))
        self.need_m110 = self.need_m110 and not line.numbered
        self.queued.append(line)

    def add_emergency(self, text: str) -> None:
        """Write *text* unnumbered before anything else; live unless it is M112."""
        line = Line(text, internal=True)
        line.wire = line.text
        self.urgent.append(line)
        if line.word != "M112":
            self.live.append(line)

    def take_unwritten(self) -> list[Line]:
        """Emergency lines, then the outbox, stamped as written now."""
        lines = [*self.urgent, *self.outbox]
        self.urgent.clear()
        self.outbox.clear()
        for line in lines:
            line.sent_at = self.clock
        return lines

    # -- framing and room ------------------------------------------------------------

    def frame(self, line: Line) -> None:
        """Fill in number and wire text, as the line would go out next.

        The same framing as checksum.format_line: the checksum of `N<n> <text>`
        is that of `N<n> ` xor that of the text, and the text's is kept. A line
        already framed with the number it would get now is left as it is: a line
        is asked about several times on its way (can_send, send, the pump).
        """
        if not line.numbered:
            line.wire = line.text
            return
        if line.m110 is not None:
            number = line.m110
        elif line.resend:
            number = line.number
        else:
            number = self._projected_number(line)
        if line.wire and number == line.number:
            return
        line.number = number
        text = line.text
        known, value = self._checksummed
        if text is not known and text != known:
            value = checksum(text)
            self._checksummed = (text, value)
        head = f"N{line.number} "
        line.wire = f"{head}{text}*{checksum(head) ^ value}"

    def _projected_number(self, line: Line) -> int:
        n = 1 if self.need_m110 else self.next_n
        if not self.queued:
            return n
        for queued in self.queued:
            if queued is line:
                break
            if queued.m110 is not None:
                n = queued.m110 + 1
            elif queued.numbered:
                n += 1
        return n

    def room_for(self, line: Line, max_lines: int) -> bool:
        """W2-W3: may *line* go live now, with at most *max_lines* live?

        Nothing goes while draining or while an M110 is live (F3); with nothing
        live any one line may go (W3); else the line and byte budgets decide.
        """
        if self.drain_until is not None:
            return False
        live = self.live
        if not live:
            return True
        if line.m110 is not None or len(live) >= max_lines:
            return False
        used = self.dead_bytes + len(line.wire) + 1
        for other in live:  # one pass: an M110 live, and the bytes charged
            if other.m110 is not None:
                return False
            used += len(other.wire) + 1
        return used <= self._rx_buffer

    def add_probe(self, text: str) -> None:
        """T6: a numbered internal line straight to the wire, beyond the window."""
        line = Line(text, None, internal=True, numbered=True)
        self.frame(line)
        self._number(line)
        self.live.append(line)
        self.outbox.append(line)

    def push_next(self) -> None:
        """T6: the next line to re-send goes now, beyond the window (a probe)."""
        line = self._peek()
        if line is not None and line.resend:
            self.rewind_next += 1
            self.live.append(line)
            self.outbox.append(line)

    def hold(self, rtt: float) -> None:
        """R1: write nothing for a drain delay (the ok of a Resend comes first)."""
        drain = self._rx_buffer * 10 / self._baud + rtt
        self.drain_until = max(self.drain_until or 0.0, self.clock + drain)

    def oldest_unacked(self) -> int:
        """The number of the oldest numbered line not acknowledged yet (R7)."""
        oldest = self.rewind_next if self.rewinding else self.next_n
        for line in self.live:
            if line.number is not None and line.number < oldest:
                oldest = line.number
        return oldest

    def m110_next(self) -> bool:
        """True when the M110 itself waits to be re-sent."""
        return self.rewind_next == self.history.first < self.rewind_end

    def m110_live(self) -> bool:
        return any(line.m110 is not None for line in self.live)

    # -- moving lines ----------------------------------------------------------------

    @property
    def has_lines_to_move(self) -> bool:
        """Whether `pump` has anything to do: lines queued or to re-send, or the
        tags of a finished re-send to forget."""
        return bool(
            self.queued or self.rewind_next < self.rewind_end or self.rewind_tags
        )

    def pump(self, max_lines: int) -> None:
        """Move lines to re-send, then queued lines, to the wire while W2 allows."""
        while (line := self._peek()) is not None and self.room_for(line, max_lines):
            if line.resend:
                self.rewind_next += 1
            else:
                self.queued.popleft()
                self._number(line)
            self.live.append(line)
            self.outbox.append(line)
        if self.rewind_next >= self.rewind_end:
            self.rewind_tags.clear()

    def go_live(self, line: Line) -> None:
        """*line*, framed, goes live now: the pump's step for the head of an empty
        queue, for a line the caller found room for (room_for) with nothing queued,
        re-sent or owed (an M110) before it."""
        self._number(line)
        self.live.append(line)
        self.outbox.append(line)
        if self.rewind_tags:
            self.rewind_tags.clear()

    def _peek(self) -> Line | None:
        if self.rewind_next < self.rewind_end:
            n = self.rewind_next
            old = self.rewind_tags.get(n)
            text = self.history.get(n)
            line = Line(text, None, internal=True, numbered=True, number=n, resend=True)
            if old is not None:
                line.tag, line.internal, line.m110 = old.tag, old.internal, old.m110
            elif _M110.match(text):
                line.m110 = n
        elif self.queued:
            line = self.queued[0]
        else:
            return None
        self.frame(line)
        return line

    def _number(self, line: Line) -> None:
        if line.number is None:
            return
        if line.m110 is not None:
            self.history.clear(line.number)
        self.history.append(line.number, line.text)
        self.next_n = line.number + 1

    def skip_unsent_before(self, m: int) -> list[Line]:
        """Drop lines < m from the re-send; returns the dead lines they stood for."""
        skipped: list[Line] = []
        while self.rewind_next < min(m, self.rewind_end):
            old = self.rewind_tags.pop(self.rewind_next, None)
            if old is not None:
                skipped.append(old)
            self.rewind_next += 1
        return skipped

    def rewind(self, n: int, rtt: float) -> int:
        """R2: live lines >= n die and lines n.. go again; returns how many died.

        Written dead lines stay charged until rx_buffer*10/baud + *rtt* has passed.
        """
        dead = [
            line for line in self.live if line.number is not None and line.number >= n
        ]
        if dead:
            for lines in (self.live, self.outbox):  # in place: others hold them
                kept = [line for line in lines if line not in dead]
                lines.clear()
                lines.extend(kept)
            written = sum(line.cost for line in dead if line.sent_at is not None)
            if written:
                self.dead_bytes += written
                drain = self._rx_buffer * 10 / self._baud + rtt
                self.drain_until = max(self.drain_until or 0.0, self.clock + drain)
        tags = {k: v for k, v in self.rewind_tags.items() if k >= n}
        tags.update((line.number, line) for line in dead if line.number is not None)
        self.rewind_next, self.rewind_end, self.rewind_tags = n, self.next_n, tags
        return len(dead)
