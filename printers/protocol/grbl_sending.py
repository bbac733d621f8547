"""GrblProtocol's sending: whether a line fits GRBL's RX buffer now, a mixin.

Character counting and the sync rules (an EEPROM write goes alone, once GRBL has
settled) decide; `offer` is the stream host's one call a line. The rules table is
in grbl.py; a line's wire text comes from grbl_lines.prepare_line.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from printers.protocol.errors import CommandRejected, LocalProtocolError
from printers.protocol.grbl_lines import Line, prepare_line

if TYPE_CHECKING:
    from printers.protocol.grbl import GrblProtocol

__all__ = ["WAIT_SETTLED", "Sending"]

WAIT_SETTLED = "an EEPROM write waits until GRBL reports Idle"


class Sending:
    """Character counting and the sync rules: the sending half of GrblProtocol."""

    def can_send(self: GrblProtocol, text: str) -> bool:
        """True when *text* fits GRBL's RX buffer now and no sync rule holds it back.

        A line send() would reject gives True, so that send() raises and says why
        instead of the stream waiting forever.
        """
        try:
            line = self._prepare(text, None)
        except CommandRejected:
            return True
        return self._hold(line) is None

    def send(self: GrblProtocol, text: str, now: float, *, tag: object = None) -> None:
        """Queue one cleaned command; Ack(tag) or CommandFailed(tag) follows later."""
        if self.offer(text, now, tag=tag):
            return
        line = self._prepare(text, tag)
        raise LocalProtocolError(
            f"cannot send '{line.text}' now: {self._blocker(line)}"
        )

    def offer(self: GrblProtocol, text: str, now: float, *, tag: object = None) -> bool:
        """`send` when `can_send` would say yes, preparing the line once; False (the
        line left out) when it cannot go now. A line GRBL could never take raises
        CommandRejected."""
        self._now = now
        line = self._prepare(text, tag)
        if self._hold(line) is not None:
            return False
        self._queue(line, now)
        return True

    def _hold(self: GrblProtocol, line: Line) -> str | None:
        """`_blocker`; a line waiting for GRBL to settle asks for a report."""
        blocker = self._blocker(line)
        if blocker == WAIT_SETTLED:
            self._want_settled = True
        return blocker

    def _queue(self: GrblProtocol, line: Line, now: float) -> None:
        if line.sync:
            self._want_settled = False
        if not self.in_flight:
            self._progress_at = now
            self._stall_reported = False
        self._outbox.append(line)

    def _prepare(self: GrblProtocol, text: str, tag: object) -> Line:
        """prepare_line, parsing each text once (CommandRejected as it raises)."""
        known, wire, sync, dwell = self._prepared
        if text is not known and text != known:
            ready = prepare_line(text, None, self.max_line_length, compact=self.compact)
            wire, sync, dwell = ready.text, ready.sync, ready.dwell
            self._prepared = (text, wire, sync, dwell)
        return Line(wire, tag, sync, dwell)

    def _blocker(self: GrblProtocol, line: Line) -> str | None:
        """Why *line* cannot go now, or None when it can."""
        if self._reset_sent_at is not None:
            return "a soft reset was sent and GRBL has not restarted yet"
        used, sync = 0, False
        for queue in (self._outbox, self._waiting):
            for other in queue:
                used += len(other.text) + 1
                sync = sync or other.sync
        if sync:
            return "an EEPROM write is waiting for its answer"
        if line.sync and (self._outbox or self._waiting):
            return "an EEPROM write goes only when nothing else is in flight"
        if line.sync and self.wait_for_idle and not self._settled:
            return WAIT_SETTLED
        if used + line.size > self.rx_buffer:
            return f"GRBL's RX buffer has {self.rx_buffer - used} bytes free"
        return None
