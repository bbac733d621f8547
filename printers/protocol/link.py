"""The contract every firmware protocol keeps (Marlin, GRBL): what the worker may call.

A protocol is sans-IO: bytes and `now` (seconds, monotonic, always passed in) go in;
bytes and events come out. It never reads a clock, sleeps, logs or touches a port.

Calling pattern, once per turn of the worker loop:

    protocol.receive_data(transport.read(timeout), now)   # b"" = nothing arrived
    while (event := protocol.next_event()) is not None:
        handle(event)
    while protocol.offer(text, now, tag=...):             # the window took it
        text = next command
    transport.write(protocol.data_to_send())
    if deadline := protocol.next_deadline(): wait at most until it, then
    protocol.handle_timeout(now)
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from collections import deque

    from printers.protocol.events import Event


class LinkProtocol(Protocol):
    """Duck type of MarlinProtocol and GrblProtocol."""

    #: True while a job is streaming (Marlin numbers lines "only while printing").
    printing: bool
    #: True while the firmware writes every line into a file (Marlin's M28): the
    #: protocol sends nothing of its own then.
    writing_file: bool
    #: A command to send after a job's last line, whose answer proves the firmware
    #: got every line before it (Marlin: a numbered M105); None when there is none.
    closing_sync: str | None
    #: The events not taken yet, oldest first: what `next_event` pops (a loop may
    #: take them from here, without a call for each).
    events: deque[Event]

    def can_send(self, text: str) -> bool:
        """True when *text* may go now without breaking the window or a sync rule."""
        ...

    def send(self, text: str, now: float, *, tag: object = None) -> None:
        """Queue one command (already cleaned: no comment, no newline) for the wire.

        Raises CommandRejected for a line the firmware cannot take (too long, not
        ASCII, empty). The caller gets Ack(tag) or CommandFailed(tag) later.
        """
        ...

    def offer(self, text: str, now: float, *, tag: object = None) -> bool:
        """`send` *text* if `can_send` would allow it now, checking the line once;
        False, and nothing queued, when the window has no room for it yet.

        Raises CommandRejected, as send() does, for a line the firmware cannot take.
        """
        ...

    def send_emergency(self, text: str, now: float) -> None:
        """Send an emergency command ahead of everything queued, even with the window full.

        Marlin: M112, M108, M410 as unnumbered lines. GRBL: realtime bytes, given
        as text of one character ("!", "~", "?", "\\x18", "\\x85", overrides).
        """
        ...

    def reset_line_numbers(self, now: float) -> None:
        """Start numbering again (Marlin sends `M110 N0`; GRBL has nothing to do)."""
        ...

    def receive_data(self, data: bytes, now: float) -> None:
        """Feed bytes from the firmware; b"" means nothing arrived (not end of stream)."""
        ...

    def next_event(self) -> Event | None:
        """The next event, or None when more data is needed."""
        ...

    def data_to_send(self) -> bytes:
        """Bytes to write now, in one write call (whole lines); b"" when nothing."""
        ...

    def next_deadline(self) -> float | None:
        """When handle_timeout() must be called if nothing arrives before; None = never."""
        ...

    def handle_timeout(self, now: float) -> None:
        """Act on a passed deadline: retransmit, tickle, or give up with LinkFailed."""
        ...

    def abandon(self) -> None:
        """Forget everything queued and in flight (after a reset, a halt or a reconnect).

        Tags still unanswered are dropped without events.
        """
        ...

    @property
    def in_flight(self) -> int:
        """Commands sent and not yet answered."""
        ...
