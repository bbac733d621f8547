"""The printer's own SD card on the worker's side: its listing, prints from it, uploads.

One `SdCardWatch` per worker, reset on every connection and firmware reset. It reads
the firmware's words about the card (`printers/protocol/marlin_sd.py`) from every
response line and acts on the job the card is part of:

    event (Marlin's words)            print from the card (M23, M24)   upload (M28..M29)
    Writing to file: NAME             -                                release the hold
    open failed, File: NAME           the job fails                    the job fails
    File opened: NAME Size: n         the job's size                   -
    SD printing byte p/n              progress (bytes p of n)          -
    Done printing file                the job completes                -
    Not SD printing (lines acked,     the printer stopped by itself:   -
      not paused, nothing queued)     the job is aborted
    Begin file list .. End file list  Printer.sd_card (listing)
    Cap:SDCARD / AUTOREPORT_SD_STATUS M20 at connect / `M27 S2` instead of polling M27

Uploads are numbered and checked line by line like any stream; the protocol sends
nothing of its own while the firmware writes (`writing_file`), and the stream host
lets nothing else through (an exclusive stream).
"""

from __future__ import annotations

import itertools
import re
from typing import TYPE_CHECKING, Any

from django.db.models import Min

from jobs.gcode import iter_commands
from jobs.models import Job
from printers.dbclock import shared_now
from printers.protocol.marlin_sd import (
    SdCardState,
    SdDeleted,
    SdDeleteFailed,
    SdDialogue,
    SdDone,
    SdEvent,
    SdFileOpened,
    SdListed,
    SdNotPrinting,
    SdOpenFailed,
    SdProgress,
    SdWriting,
)
from printers.streaming import (
    CommandState,
    Line,
    PrinterSide,
    Stream,
    StreamType,
)

if TYPE_CHECKING:
    from printers.worker.loop import PrinterWorker

__all__ = ["SD_POLL_SECONDS", "SdCardWatch"]

#: M27 is polled this often during a print from the card when the firmware does not
#: report by itself; with AUTOREPORT_SD_STATUS it is asked to (`M27 S<n>`).
SD_POLL_SECONDS = 2
#: The card's listing with long names where the firmware has them (others ignore L).
LIST = "M20 L"
#: Lines of a file not copied to the card (`upload_stream`).
_NOT_COPIED = re.compile(r"^\s*(?:M28\b|\[ESP)|M29(?![0-9])", re.IGNORECASE)


def _lines(commands: list[str]) -> list[Line]:
    """Commands as they are: a card name is not cleaned of what looks like a comment."""
    return [Line(index, text) for index, text in enumerate(commands)]


def _same_file(a: str, b: str) -> bool:
    return a.strip().upper().lstrip("/") == b.strip().upper().lstrip("/")


#: Pause with M25 (every firmware), then abort with M524 (Marlin 2): an older firmware
#: that does not know M524 still stops reading the file.
_PRINT_CONTROLS = {"pause": "M25", "resume": "M24", "abort": "M25\nM524"}


class SdCardWatch:
    """What the worker knows of the printer's SD card, and the job that uses it."""

    def __init__(self, worker: PrinterWorker) -> None:
        self.worker = worker
        self.dialogue = SdDialogue()
        #: Cap:AUTOREPORT_SD_STATUS: the firmware reports progress by itself.
        self.autoreport = False
        self.next_poll = 0.0
        self._sizes: dict[int, int] = {}
        self._list_queued = False

    def reset(self) -> None:
        """A new connection or a firmware reset: what the dialogue held is gone."""
        self.dialogue = SdDialogue()
        self.autoreport = False
        self.next_poll = 0.0
        self._list_queued = False

    # -- the streams of SD jobs ------------------------------------------------------

    def print_stream(self, job: Job) -> Stream:
        """Select the card's file and start it; the printer runs it from there."""
        commands = [f"M23 {job.sd_name}", "M24"]
        if self.autoreport:
            commands.append(f"M27 S{SD_POLL_SECONDS}")
        side = PrinterSide(
            file=job.sd_name, runs_file=True, controls=dict(_PRINT_CONTROLS)
        )
        return Stream(
            StreamType.SD_FILE_STREAM,
            _lines(commands),
            name=job.name,
            ref=job.pk,
            origin=job.origin,
            printer_side=side,
        )

    def upload_stream(self, job: Job) -> Stream:
        """`M28 <name>`, the stored file's commands (read lazily), `M29`.

        Left out of the copy: M28, and any line Marlin takes for M29 ("M29" anywhere
        not followed by a digit, `M117 Copy M29 ok` too), which would close the
        file early and make the printer run the rest; and `[ESPxxx]` lines, which
        are printhost's to run, not the card's to keep (run during a copy, they
        would act on the printer meanwhile).
        """
        name = job.sd_name
        body = (
            Line(c.index + 1, c.text, c.end_offset)
            for c in iter_commands(job.path)
            if not _NOT_COPIED.search(c.text)
        )
        lines = itertools.chain(
            [Line(0, f"M28 {name}")],
            body,
            [Line(job.line_count + 1, "M29", job.size_bytes)],
        )
        side = PrinterSide(
            file=name,
            exclusive=True,
            hold_after=1,
            hold_reason=(
                f"the printer did not open {name} on its SD card for writing "
                "(no SD card, or no SD support?); nothing was written"
            ),
            controls={"abort": f"M29\nM30 {name}"},
            scripts=False,
            pausable=False,
            why_not=(
                "a copy to the SD card cannot pause: the printer writes every line "
                "it gets into the file; abort it instead"
            ),
        )
        return Stream(
            StreamType.SD_FILE_STREAM,
            lines,
            name=f"{job.name} -> SD:{name}",
            ref=job.pk,
            origin=job.origin,
            printer_side=side,
        )

    def writing(self) -> bool:
        """An upload is writing the card's file: nothing else may reach the firmware."""
        stream, side = self._current()
        return bool(side and side.exclusive and side.released and not stream.finished)

    # -- requests ----------------------------------------------------------------------

    def list_card(self) -> str:
        """Queue M20; returns an error message or ""."""
        if self.worker.printer.is_grbl:
            return "GRBL has no SD card"
        if self.worker.transport is None:
            return "printer offline"
        self.worker.submit_internal(LIST)
        self._list_queued = True
        return ""

    def delete(self, name: str) -> str:
        """Queue M30 <name> and a new listing; returns an error message or ""."""
        if self.worker.printer.is_grbl:
            return "GRBL has no SD card"
        if self.worker.transport is None:
            return "printer offline"
        stream, side = self._current()
        # Marlin reads a leading / as the card's root: /cube.gco is CUBE.GCO.
        if side is not None and _same_file(side.file, name):
            return f"{name} is in use by job {stream.ref}; abort the job first"
        lines = _lines([f"M30 {name}", LIST])
        self.worker.host.submit(
            Stream(StreamType.MULTIPLE_COMMANDS, lines, name=f"delete {name}")
        )
        return ""

    # -- what the firmware says ------------------------------------------------------

    def on_capability(self, name: str, *, enabled: bool) -> None:
        if name == "AUTOREPORT_SD_STATUS":
            self.autoreport = enabled
        elif name == "SDCARD" and enabled and not self._list_queued:
            self.list_card()
        elif name == "SDCARD":
            self._save_card(
                present=False,
                files=[],
                message="the firmware has no SD card support (Cap:SDCARD:0)",
            )

    def receive(self, text: str) -> None:
        """One response line; acts when it is about the card."""
        event = self.dialogue.receive(text)
        if event is not None:
            self._on_event(event)

    def _on_event(self, event: SdEvent) -> None:
        host = self.worker.host
        stream, side = self._current()
        printing = side is not None and side.runs_file
        match event:
            case SdListed(files=files):
                self._list_queued = False
                listing = [
                    {"name": f.name, "size": f.size, "long_name": f.long_name}
                    for f in files
                ]
                self._save_card(present=True, files=listing, message="")
            case SdCardState(present=present, message=message):
                self._save_card(present=present, message=message)
                if present and not self._list_queued:
                    self.list_card()  # a card was put in (or the printer booted)
            case SdWriting() if side is not None and side.exclusive:
                host.release(stream)
            case SdOpenFailed(name=name) if side is not None:
                host.fail_stream(f"the printer could not open {name} on its SD card")
            case SdFileOpened(size=size) if printing:
                self._save_size(stream, size)
            case SdProgress(position=position, total=total) if printing:
                stream.bytes_acked = position
                self._save_size(stream, total)
            case SdDone() if printing:
                if isinstance(stream.ref, int) and stream.ref in self._sizes:
                    stream.bytes_acked = self._sizes[stream.ref]  # read to its end
                host.printer_done(stream)
            case SdNotPrinting() if printing and self._stopped_by_printer(stream):
                host.request_abort(
                    f"the printer stopped printing {side.file} by itself "
                    "(cancelled on its display?)"
                )
            case SdDeleted(name=name):
                self.worker.note(f"deleted {name} from the printer's SD card")
            case SdDeleteFailed(name=name):
                self.worker.note(f"the printer could not delete {name} from its card")

    def _stopped_by_printer(self, stream: Stream) -> bool:
        """`Not SD printing` while we believe it prints: lines acked, not paused and
        no pause asked (the display's pause sends //action:pause first), no control
        command (a resume's M24) on its way, the file not done."""
        side = stream.printer_side
        host = self.worker.host
        return (
            side is not None
            and not side.done
            and stream.drained
            and stream.state is CommandState.WAIT_FOR_ACK
            and not host.requested
            and not host.script_queue
        )

    # -- progress and the end of a job ---------------------------------------------

    def poll(self, now: float) -> None:
        """Ask M27 during a print from the card when the firmware does not report."""
        stream, side = self._current()
        if side is None or not side.runs_file or self.autoreport:
            return
        if now < self.next_poll or not stream.drained:
            return
        if stream.state is not CommandState.WAIT_FOR_ACK:
            return
        self.next_poll = now + SD_POLL_SECONDS
        self.worker.submit_internal("M27")

    def job_ended(self, stream: Stream, state: str) -> None:
        """After an SD job's outcome is saved: stop reports, list the card, print after."""
        side = stream.printer_side
        if side is None:
            return
        if side.runs_file and self.autoreport:
            self.worker.submit_internal("M27 S0")
        if side.exclusive:
            self.list_card()
        if side.exclusive and state == Job.State.COMPLETED:
            self._print_after(stream)

    def _print_after(self, stream: Stream) -> None:
        """Queue a print of the copied file at the head of the queue, if asked."""
        job = Job.objects.filter(pk=stream.ref, print_after=True).first()
        if job is None:
            return
        head = Job.objects.filter(
            printer_id=job.printer_id, state=Job.State.QUEUED
        ).aggregate(head=Min("position"))["head"]
        with self.worker.lease.held():
            printing = Job.objects.create(
                printer_id=job.printer_id,
                kind=Job.Kind.SD_PRINT,
                name=job.name,
                sd_name=job.sd_name,
                position=(head - 1) if head is not None else job.position + 1,
                origin=job.origin,
                uploaded_by_id=job.uploaded_by_id,
            )
        # Written on the worker's own connection, which an SQLite poll does not
        # count as news (Wakeups.quiet): the queue is looked at without a poll.
        self.worker.look_for_jobs = True
        self.worker.note(
            f"job {printing.pk} prints {job.sd_name} from the SD card next"
        )

    # -- helpers -----------------------------------------------------------------------

    def _current(self) -> tuple[Stream, PrinterSide] | tuple[None, None]:
        stream = self.worker.host.current_stream
        if stream is None or stream.printer_side is None:
            return None, None
        return stream, stream.printer_side

    def _save_size(self, stream: Stream, size: int) -> None:
        job_id = stream.ref
        if not isinstance(job_id, int) or size <= 0 or self._sizes.get(job_id) == size:
            return
        self._sizes[job_id] = size
        with self.worker.lease.held():
            Job.objects.filter(pk=job_id).update(size_bytes=size)

    def _save_card(self, **values: Any) -> None:
        card = dict(self.worker.status.fields.get("sd_card") or {})
        card.update(values, listed=shared_now().isoformat())
        if not card.get("present"):
            card["files"] = []
        self.worker.status.update(sd_card=card)
