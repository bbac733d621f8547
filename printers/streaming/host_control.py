"""The stream host's pause, resume and abort: requests, scripts and their states.

A mixin of StreamHost (host.py): `request_pause/resume/abort` record what an
external request (operation 1) or the printer itself asked for; the active stream
applies it at its next step (`_take_request`), running the printer's scripts and
its own control commands (an SD print's M25/M24/M524, printer_side.py).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from printers.streaming.host_events import StreamPaused, StreamResumed
from printers.streaming.printer_side import control_stream, runs_scripts
from printers.streaming.streams import (
    REQUEST_MOVES,
    REQUESTS_FROM,
    CommandState,
    Stream,
    StreamType,
    lines_from_text,
)

if TYPE_CHECKING:
    from printers.streaming.host import StreamHost

S = CommandState


class StreamControl:
    """Pause, resume, abort and the printer's scripts (see the module's doc)."""

    def run_script(
        self: StreamHost, name: str, *, origin: str = "host"
    ) -> Stream | None:
        """Queue the printer's script *name* (pause, resume, abort...) if it has one;
        one the firmware's coming reset would cancel (`after_reset`) is held until
        `run_held_scripts`."""
        if name in self.after_reset:
            if self.scripts.get(name, "").strip():
                self.held_scripts.append(name)
            return None
        return self._queue_script(name, origin)

    def run_held_scripts(self: StreamHost) -> None:
        """The firmware reset: queue the scripts held for it, in order."""
        held, self.held_scripts = self.held_scripts, []
        for name in held:
            self._queue_script(name, "host")

    def _queue_script(self: StreamHost, name: str, origin: str) -> Stream | None:
        lines = lines_from_text(self.scripts.get(name, ""))
        if not lines:
            return None
        stream = Stream(
            StreamType.MULTIPLE_COMMANDS, lines, name=f"{name} script", origin=origin
        )
        self.script_queue.append(stream)
        return stream

    def request_pause(self: StreamHost, *, script: bool = True) -> str:
        """Ask the active stream to pause; returns an error message or "".

        Without *script* the printer paused itself: the pause script is not run.
        """
        stream = self.current_stream
        if stream is None:
            return "no stream is running"
        if stream.state in (S.PAUSE, S.PAUSED):
            return "the stream is already paused"
        side = stream.printer_side
        if side is not None and not side.pausable:
            return side.why_not or "this stream cannot pause"
        self._requested, self._with_script = "pause", script
        return ""

    def request_resume(self: StreamHost, *, script: bool = True) -> str:
        """Ask the paused stream to resume (without *script*: the printer did).

        A pause asked but not applied yet is simply dropped (the printer paused
        and resumed itself before the stream could stop).
        """
        stream = self.current_stream
        if stream is not None and self._requested == "pause":
            self._requested, self._with_script = "", True
            return ""
        if stream is None or stream.state is not S.PAUSED:
            return "no stream is paused"
        self._requested, self._with_script = "resume", script
        return ""

    def release(self: StreamHost, stream: Stream) -> None:
        """The printer confirmed what *stream* holds for (M28 opened the file)."""
        if stream.printer_side is not None:
            stream.printer_side.released = True

    def printer_done(self: StreamHost, stream: Stream) -> None:
        """The printer finished the file *stream* handed it (`Done printing file`)."""
        if stream.printer_side is not None:
            stream.printer_side.done = True

    def request_abort(self: StreamHost, message: str = "aborted by request") -> str:
        if self.current_stream is None:
            return "no stream is running"
        self._requested = "abort"
        self._abort_message = message
        return ""

    # -- their command states ----------------------------------------------------

    def _on_pause(self: StreamHost, stream: Stream, now: float) -> bool:
        if self._with_script:
            self._control(stream, "pause")
            if runs_scripts(stream):
                self.run_script("pause")
        self._with_script = True
        stream.move(S.PAUSED)
        self._events.append(StreamPaused(stream))
        return True

    def _on_paused(self: StreamHost, stream: Stream, now: float) -> bool:
        return self._take_request(stream)

    def _on_resume(self: StreamHost, stream: Stream, now: float) -> bool:
        if self._with_script:
            if runs_scripts(stream):
                self.run_script("resume")
            self._control(stream, "resume")
        self._with_script = True
        stream.move(S.READY_TO_READ_CURSOR)
        self._events.append(StreamResumed(stream))
        return True

    def _on_abort(self: StreamHost, stream: Stream, now: float) -> bool:
        self._control(stream, "abort")
        if runs_scripts(stream):
            self.run_script("abort")
        stream.move(S.END)
        self._finish(stream, "aborted", self._abort_message)
        return True

    def _control(self: StreamHost, stream: Stream, action: str) -> None:
        """Queue the printer's own command for *action*; an exclusive stream's first
        (nothing queued behind it may reach the firmware before its file is closed)."""
        control = control_stream(stream, action)
        side = stream.printer_side
        if control is not None and side is not None and side.exclusive:
            self.script_queue.appendleft(control)
        elif control is not None:
            self.script_queue.append(control)

    def _take_request(self: StreamHost, stream: Stream) -> bool:
        """Apply a pending pause/resume/abort to the stream queue's head."""
        if not self._requested or stream is not self.current_stream:
            return False
        wanted, self._requested = self._requested, ""
        target = REQUEST_MOVES[wanted]
        if target not in REQUESTS_FROM[stream.state]:
            return False
        stream.move(target)
        return True
