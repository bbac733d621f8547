"""The stream host: ESP3D's three queues and the per-stream command states, sans-IO.

It is the spooler's brain (MeerK40t): the worker owns the loop and the I/O, the host
decides which line goes next. Each call to `advance(now)` does ESP3D's operations 2
and 3: choose the active stream (emergency > script queue > stream queue) and move
its command state until it has to wait. Step 1 (external requests) arrives through
`request_pause/resume/abort` (host_control.py) and `submit`; step 4 (the rx queue)
through `handle_ack/handle_failed` called by the worker for the protocol's events.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

from printers.protocol.errors import CommandRejected
from printers.streaming.host_control import StreamControl
from printers.streaming.host_events import (
    CommandAnswered,
    EspCommand,
    HostEvent,
    StreamEnded,
    StreamStarted,
)
from printers.streaming.printer_side import (
    complete,
    exclusive_now,
    holding,
)
from printers.streaming.streams import (
    CommandState,
    Line,
    QueueState,
    Stream,
)

if TYPE_CHECKING:
    from collections.abc import Collection

    from printers.protocol.link import LinkProtocol

S = CommandState
#: Line.index of a closing sync: not one of the stream's lines, never counted.
CLOSING = -1


class StreamHost(StreamControl):
    """Queues streams and feeds their lines to a LinkProtocol as its window allows."""

    def __init__(
        self,
        protocol: LinkProtocol,
        *,
        scripts: dict[str, str] | None = None,
        max_steps: int = 512,
        after_reset: Collection[str] = (),
    ) -> None:
        """*after_reset*: scripts the firmware's reset would cancel, which the
        caller resets it after (GRBL's abort: a feed hold, then a soft reset that
        empties its buffers): held until `run_held_scripts`."""
        self.protocol = protocol
        self.scripts = dict(scripts or {})
        self.after_reset = frozenset(after_reset)
        self.held_scripts: list[str] = []
        self.stream_queue: deque[Stream] = deque()
        self.script_queue: deque[Stream] = deque()
        self.emergency_queue: deque[str] = deque()
        self._max_steps = max_steps
        self._events: deque[HostEvent] = deque()
        self._pending: dict[int, Line] = {}
        self._requested: str = ""
        #: False when the printer paused/resumed itself (//action:paused, resumed).
        self._with_script = True
        self._abort_message = ""

    # -- requests (operation 1) ------------------------------------------------

    def submit(self, stream: Stream) -> None:
        """Put *stream* in the queue its type belongs to."""
        if stream.type.is_stream:
            self.stream_queue.append(stream)
        elif stream.type.is_script:
            self.script_queue.append(stream)
        else:
            raise ValueError(f"stream type {stream.type.value} cannot be streamed")

    def emergency(self, text: str) -> None:
        """Queue an emergency command: it goes out on the next advance, ahead of all."""
        self.emergency_queue.append(text)

    # -- the protocol's answers (operation 4) ---------------------------------

    def handle_ack(self, tag: object) -> None:
        """The firmware acknowledged the line sent with *tag*."""
        if not isinstance(tag, tuple):
            return
        stream, line = tag
        if line.index == CLOSING:
            stream.sync = "done"
            return
        stream.acked += 1
        if line.end_offset > stream.bytes_acked:
            stream.bytes_acked = line.end_offset
        if line.index >= stream.done:
            stream.done = line.index + 1
        if stream.type.is_script:
            self._events.append(CommandAnswered(stream, line, ok=True))

    def handle_failed(self, tag: object, message: str) -> None:
        """The firmware refused the line sent with *tag* (GRBL `error:N`)."""
        if not isinstance(tag, tuple):
            return
        stream, line = tag
        stream.acked += 1
        if line.index >= stream.done:
            stream.done = line.index + 1
        text = f"line {line.index + 1} {line.text!r}: {message}"
        if stream.type.is_script:
            self._events.append(CommandAnswered(stream, line, ok=False, message=text))
        if not stream.finished and stream.state is not S.ERROR:
            self._fail(stream, text)

    def handle_resend(self) -> None:
        """A resend is being served: show it in the active stream's state."""
        stream = self.active_stream
        if stream is not None and stream.state is S.WAIT_FOR_ACK:
            stream.move(S.RESEND_GCODE_COMMAND)

    def fail_stream(self, message: str) -> bool:
        """Stop the stream queue's head with *message*; False if there is none."""
        stream = self.current_stream
        if stream is None or stream.state in (S.END, S.ERROR):
            return False
        self._fail(stream, message)
        return True

    def fail_all(self, message: str, *, outcome: str = "failed") -> None:
        """Every queued stream ends with *outcome* and *message* (reset, halt, lost link)."""
        for queue in (self.script_queue, self.stream_queue):
            while queue:
                stream = queue.popleft()
                if stream.state is S.ERROR:
                    stream.outcome = "failed"
                elif stream.state is not S.END:
                    stream.outcome, stream.message = outcome, message
                stream.state = S.END
                self._events.append(StreamEnded(stream))
        self._pending.clear()
        self._requested = ""

    # -- operations 2 and 3 --------------------------------------------------

    def advance(self, now: float) -> None:
        """Send emergencies, then step the active stream until it must wait."""
        while self.emergency_queue:
            self.protocol.send_emergency(self.emergency_queue.popleft(), now)
        # Each step advances the stream by one command state (`_on_<state>`);
        # False when it has to wait.
        handlers = _HANDLERS
        for _ in range(self._max_steps):
            stream = self.active_stream
            if stream is None or not handlers[stream.state](self, stream, now):
                return

    def next_event(self) -> HostEvent | None:
        return self._events.popleft() if self._events else None

    @property
    def active_stream(self) -> Stream | None:
        """Emergency > script queue > stream queue: the stream whose lines go next."""
        queue = self.stream_queue
        current = queue[0] if queue else None
        if (
            current is not None
            and current.printer_side is not None
            and exclusive_now(current)
        ):
            return current  # scripts wait: the firmware would write them to the file
        if self.script_queue:
            return self.script_queue[0]
        return current

    @property
    def current_stream(self) -> Stream | None:
        """The head of the stream queue ([ESP701] controls it)."""
        return self.stream_queue[0] if self.stream_queue else None

    @property
    def queue_state(self) -> QueueState:
        stream = self.current_stream
        if stream is None:
            return QueueState.IDLE
        if stream.state in (S.PAUSE, S.PAUSED):
            return QueueState.PAUSED
        return QueueState.PROCESSING

    @property
    def requested(self) -> str:
        """A pause, resume or abort asked for and not applied yet ("" if none)."""
        return self._requested

    @property
    def printing(self) -> bool:
        """A file stream is running (Marlin numbers its lines "only while printing"):
        queue_state is PROCESSING, asked every turn."""
        queue = self.stream_queue
        return bool(queue) and queue[0].state not in (S.PAUSE, S.PAUSED)

    @property
    def has_events(self) -> bool:
        """Events wait for `next_event` (asked every turn, most of which have none)."""
        return bool(self._events)

    # -- one step of the command state machine --------------------------------

    def _on_start(self, stream: Stream, now: float) -> bool:
        stream.move(S.READY_TO_READ_CURSOR)
        self._events.append(StreamStarted(stream))
        return True

    def _on_ready_to_read_cursor(self, stream: Stream, now: float) -> bool:
        if self._requested and self._take_request(stream):
            return True
        if stream.printer_side is not None and holding(stream):
            stream.move(S.WAIT_FOR_ACK)
            return True
        line = self._pending.get(stream.id)
        if line is None:
            if stream.eof:
                line = self._closing(stream)
                if line is None:
                    stream.move(S.END if complete(stream) else S.WAIT_FOR_ACK)
                    if stream.finished:
                        self._finish(stream, "completed")
                    return stream.finished
            else:
                line = next(stream.generate(), None)
                if line is None:
                    stream.eof = True
                    return True
            if line.text.startswith("[ESP"):
                self._pending[stream.id] = line
                stream.move(S.READ_CURSOR)
                stream.move(S.SEND_ESP_COMMAND)
                return True
        # Straight on, not through advance(): nothing above changed the queues,
        # so the stream is still the active one (the same for the chains below).
        return self._send_line(stream, line, now)

    def _send_line(self, stream: Stream, line: Line, now: float) -> bool:
        """READ_CURSOR and SEND_GCODE_COMMAND in one step: the protocol takes the
        line now (`offer`), or the stream waits for room with it pending.

        The moves READY_TO_READ_CURSOR -> READ_CURSOR -> SEND_GCODE_COMMAND and on
        to READY_TO_READ_CURSOR or WAIT_FOR_ACK are all in the table, and nothing
        can happen between them: they are made as one assignment (a job line is
        one of these a turn, and the checked moves were a tenth of its cost).
        """
        try:
            taken = self.protocol.offer(line.text, now, tag=(stream, line))
        except CommandRejected as error:
            self._pending.pop(stream.id, None)
            stream.state = S.SEND_GCODE_COMMAND
            self._fail(stream, f"line {line.index + 1}: {error}")
            return True
        if not taken:
            self._pending[stream.id] = line
            stream.state = S.WAIT_FOR_ACK
            return False
        self._pending.pop(stream.id, None)
        if line.index == CLOSING:
            stream.state = S.WAIT_FOR_ACK
            return True
        stream.sent += 1
        if line.index >= stream.reached:
            stream.reached = line.index + 1
        stream.state = S.READY_TO_READ_CURSOR
        return True

    def _on_send_esp_command(self, stream: Stream, now: float) -> bool:
        line = self._pending.pop(stream.id)
        stream.sent += 1
        stream.acked += 1
        stream.reached = stream.done = max(stream.done, line.index + 1)
        self._events.append(EspCommand(stream, line.text))
        stream.move(S.READY_TO_READ_CURSOR)
        return True

    def _on_wait_for_ack(self, stream: Stream, now: float) -> bool:
        if self._requested and self._take_request(stream):
            return True
        if stream.printer_side is not None and holding(stream):
            if stream.acked < stream.sent:
                return False
            assert stream.printer_side is not None
            self._fail(stream, stream.printer_side.hold_reason or "not confirmed")
            return True
        if stream.eof and complete(stream):
            stream.move(S.END)
            self._finish(stream, "completed")
            return True
        line = self._pending.get(stream.id)
        if line is not None:
            # A line waiting for room is offered again (READY_TO_READ_CURSOR on,
            # whose checks were made above): the protocol says at once whether it
            # goes.
            return self._send_line(stream, line, now)
        if stream.eof:
            return False
        stream.move(S.READY_TO_READ_CURSOR)
        return self._on_ready_to_read_cursor(stream, now)

    def _on_resend_gcode_command(self, stream: Stream, now: float) -> bool:
        stream.move(S.WAIT_FOR_ACK)
        return True

    def _on_error(self, stream: Stream, now: float) -> bool:
        side = stream.printer_side
        if side is not None and (side.released or not side.hold_after):
            # Stop the printer's part too: an SD print must not run on, and a file
            # left open for writing would swallow every later command.
            self._control(stream, "abort")
        stream.move(S.END)
        self._finish(stream, "failed", stream.message)
        return True

    # -- helpers ---------------------------------------------------------------

    def _closing(self, stream: Stream) -> Line | None:
        """The closing sync owed after a file stream's last line (S1 in marlin.py)."""
        if stream.sync or not stream.type.is_stream or stream.printer_side is not None:
            return None
        text = self.protocol.closing_sync
        stream.sync = "owed" if text else "done"
        return Line(CLOSING, text) if text else None

    def _fail(self, stream: Stream, message: str) -> None:
        stream.message = message
        if stream.state in (S.START, S.READ_CURSOR, S.SEND_ESP_COMMAND):
            stream.state = S.READY_TO_READ_CURSOR
        stream.move(S.ERROR)

    def _finish(self, stream: Stream, outcome: str, message: str = "") -> None:
        stream.outcome = outcome
        if message:
            stream.message = message
        self._pending.pop(stream.id, None)
        for queue in (self.script_queue, self.stream_queue):
            if queue and queue[0] is stream:
                queue.popleft()
                break
        self._events.append(StreamEnded(stream))


#: Each command state's step (`_on_<state>`), looked up once, not per step.
_HANDLERS = {
    state: getattr(StreamHost, f"_on_{state.name.lower()}")
    for state in CommandState
    if hasattr(StreamHost, f"_on_{state.name.lower()}")
}
