"""ESP3D's [ESP700] (stream a stored file) and [ESP701] (stream control and status),
as the worker runs them: typed as a request, or read from a stream's lines."""

from __future__ import annotations

from typing import TYPE_CHECKING

from django.conf import settings

from jobs.gcode import BadGcode, iter_commands
from printers.streaming import Line, Stream
from printers.streaming.esp import (
    EspError,
    EspFileRequest,
    EspStreamControl,
    esp_reply,
    parse_esp,
)

if TYPE_CHECKING:
    from collections.abc import Callable

    from printers.worker.loop import PrinterWorker


#: [ESP700] read from a file may run another file (a macro calling a macro), this
#: many deep at most.
MAX_DEPTH = 4


class EspCommands:
    """RequestPoller's [ESPxxx] part; an action ([ESP701]action=PAUSE) is run as a
    request's action is (`_action`)."""

    worker: PrinterWorker
    _action: Callable[[str, str], str]

    def esp(self, text: str, origin: str, *, within: Stream | None = None) -> str:
        """Run [ESP700]/[ESP701]; the reply also goes to the response log.

        *within*: the stream the line was read from (None: a client typed it).
        """
        try:
            request = parse_esp(text)
            if isinstance(request, EspFileRequest):
                reply = self._esp_file(request, origin, within)
            else:
                reply = self._esp_control(request, origin)
        except (EspError, BadGcode) as error:
            reply = f"error: {error}"
        self.worker.log.add(reply, 4)
        return reply

    def _esp_file(
        self, request: EspFileRequest, origin: str, within: Stream | None
    ) -> str:
        from jobs.services import check_stored_file, queue_stored_file, stored_file

        printer = self.worker.printer
        if settings.PRINTHOST_WORKER_HOST:
            raise EspError(
                f"[ESP700] reads the printer's storage, which is on the control "
                f"plane, not on worker host {settings.PRINTHOST_WORKER_HOST}: queue "
                "the file there"
            )
        from_file = within is not None and within.type.is_file
        depth = within.depth + 1 if from_file and within is not None else 0
        if from_file and request.type.is_stream:
            # A job that queues a job (itself, or one that queues it back) would
            # queue jobs for ever: only a client queues one.
            raise EspError("[ESP700]stream= cannot be used inside a file")
        if depth > MAX_DEPTH:
            raise EspError(
                f"[ESP700] runs files at most {MAX_DEPTH} deep (a file that runs "
                "itself?)"
            )
        if request.type.is_stream:
            job = queue_stored_file(printer, request.path, origin=origin)
            return esp_reply(700, f"queued as job {job.pk}", as_json=request.as_json)
        path = stored_file(printer, request.path)
        if not path.is_file():
            raise EspError(
                f"[ESP700] no file {request.path!r} in the printer's storage"
            )
        check_stored_file(printer, path, name=request.path)
        lines = (Line(c.index, c.text, c.end_offset) for c in iter_commands(path))
        self.worker.host.submit(
            Stream(request.type, lines, name=request.path, origin=origin, depth=depth)
        )
        return esp_reply(700, "ok", as_json=request.as_json)

    def _esp_control(self, request: EspStreamControl, origin: str) -> str:
        action = request.action
        if action == "CLEAR_ERROR":
            self.worker.last_stream_error = ""
            return esp_reply(701, "ok", as_json=request.as_json)
        if action:
            reply = self._action(action.lower(), origin)
            ok = reply == "ok"
            return esp_reply(
                701, reply.removeprefix("error: "), as_json=request.as_json, ok=ok
            )
        message, data = self._status()
        return esp_reply(701, message, as_json=request.as_json, data=data)

    def _status(self) -> tuple[str, dict[str, object]]:
        host = self.worker.host
        stream = host.current_stream
        data: dict[str, object] = {"status": host.queue_state.value}
        if stream is not None:
            data.update(
                type=stream.type.value, name=stream.name, processed=stream.acked
            )
        if self.worker.last_stream_error:
            data["error"] = self.worker.last_stream_error
        words = [f"{k}: {v}" for k, v in data.items()]
        return ", ".join(words), data
