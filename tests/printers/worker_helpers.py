"""Helpers of the worker's tests: a worker started on a printer, a job's row, the
response log."""

from __future__ import annotations

from jobs.models import Job
from printers.models import Printer, ResponseLine
from printers.worker.loop import PrinterWorker
from tests.conftest import wait_for


def job_state(job: Job) -> Job:
    return Job.objects.get(pk=job.pk)


def wait_until_failed(worker: PrinterWorker, job: Job) -> None:
    wait_for(
        lambda: job_state(job).state == "failed", 10, "the job to fail",
        step=worker.tick,
    )  # fmt: skip


def logged(printer: Printer, **kind: int) -> list[str]:
    """The printer's response log in order (*kind*: of that kind only)."""
    lines = ResponseLine.objects.filter(printer=printer, **kind).order_by("seq")
    return list(lines.values_list("text", flat=True))


def start_worker(printer: Printer) -> PrinterWorker:
    worker = PrinterWorker(printer)
    worker.start()
    return worker
