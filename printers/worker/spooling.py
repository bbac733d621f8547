"""The worker as its printer's spooler (MeerK40t): start the next queued job when
the printer is free, save the running job's progress, and queue the worker's own
commands (M105 polls). A mixin of PrinterWorker, like Reactions."""

from __future__ import annotations

from typing import TYPE_CHECKING

from jobs.models import Job
from printers.streaming import Stream, StreamType, lines_from_text
from printers.worker import spool

if TYPE_CHECKING:
    from printers.worker.loop import PrinterWorker

__all__ = ["Spooling"]


class Spooling:
    """Claiming jobs, saving progress and the worker's own commands."""

    def maybe_claim_job(self: PrinterWorker, now: float, *, read: bool = True) -> None:
        """When idle, connected and the bed is clear, start the next queued job.

        The queue is read when *read* (a notification, or the poll) or when the
        printer's state changed since it was last found empty (a run ended).
        """
        if self.transport is None or self.halted or self.waitstart:
            return
        if self.reset_due is not None or self.expect_reset:
            return  # GRBL is being reset after a stopped job: its lines would go
        if self.host.current_stream is not None or self.host.script_queue:
            return
        if not (read or self.look_for_jobs):
            return
        if not self.requests.jobs_waiting():
            self.look_for_jobs = False
            return
        with self.lease.held():
            job = spool.claim_next(self.printer.pk)
        if job is None:
            return
        problem = self._cannot_start(job)
        if problem:
            with self.lease.held():
                spool.fail_job(job, problem)
            self.note(f"job {job.pk} failed: {problem}")
            return
        self.protocol.reset_line_numbers(now)
        self.journal.start_job()
        if job.kind == Job.Kind.SD_PRINT:
            stream = self.sd.print_stream(job)
        elif job.kind == Job.Kind.SD_UPLOAD:
            stream = self.sd.upload_stream(job)
        else:
            stream = spool.stream_for(job)
        # A resumed run brings its own start (its plan's preamble: heat, home X and
        # Y only, back to the height it stopped at): the start script would home Z
        # into the part, or probe the bed with the part on it.
        if job.kind != Job.Kind.SD_UPLOAD and not job.is_resume:
            self.start_script = self.host.run_script("start")
        self.host.submit(stream)
        self.update_state()

    def _cannot_start(self: PrinterWorker, job: Job) -> str:
        """Why a claimed job cannot start, or ""."""
        if job.on_sd_card and self.printer.is_grbl:
            return "GRBL has no SD card to print from or copy to"
        if job.kind != Job.Kind.SD_PRINT and not job.path.is_file():
            return f"the job's file {job.file} is missing"
        return ""

    def save_progress(self: PrinterWorker) -> None:
        stream = self.host.current_stream
        if stream is not None and spool.is_job(stream):
            with self.lease.held():
                spool.save_progress(stream)

    def poll_temperature(self: PrinterWorker, now: float) -> None:
        """Ask M105 when the firmware does not report temperatures by itself."""
        interval = self.printer.temperature_interval
        if self.printer.is_grbl or self.autoreport or interval <= 0 or self.halted:
            return
        if now < self.next_temperature or self.host.script_queue:
            return
        self.next_temperature = now + interval
        self.submit_internal("M105")

    def submit_internal(self: PrinterWorker, text: str) -> None:
        lines = lines_from_text(text)
        self.host.submit(Stream(StreamType.SINGLE_COMMAND, lines, name=text))

    def _dry_run(self: PrinterWorker) -> bool:
        return bool(getattr(self.protocol, "check_mode", False))
