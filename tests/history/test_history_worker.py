"""A real worker prints a real slice on the Marlin simulator over a pty: its run
ends in the history with the whole file's filament and layers."""

from __future__ import annotations

import pytest

from jobs import analysis_task
from jobs.analysing import analysis_of
from jobs.history import HistoryEntry
from jobs.models import Job
from printers.worker.loop import PrinterWorker
from tests.history.conftest import FLAT_BOX
from tests.printers.stream_checks import run_job

pytestmark = [pytest.mark.django_db, pytest.mark.slow]


def test_a_job_completed_by_a_worker_on_the_simulator_is_in_the_history(
    sim_factory, make_printer, make_job, client
):
    sim = sim_factory("marlin", "--baud", "115200", "--time-scale", "0")
    printer = make_printer(port=str(sim.link), baud=115200, slug="mk3")
    job = make_job(printer, FLAT_BOX.read_text(), name="flat-box.gcode")
    analysis_task.run(job.analysis_id)  # as the Celery task would, before it prints
    worker = PrinterWorker(printer)

    job = run_job(worker, job, timeout=120)

    assert job.state == Job.State.COMPLETED, job.message
    entry = HistoryEntry.objects.get(job_number=job.pk)
    analysed = analysis_of(job)
    assert entry.outcome == "completed"
    assert entry.lines_acked == entry.line_count == job.line_count
    assert (entry.layer, entry.layers) == (10, 10)
    assert entry.filament_used == pytest.approx(analysed.filament_total, abs=0.1)
    assert entry.started_at == job.started_at
    assert entry.finished_at == job.finished_at
    assert entry.print_seconds == pytest.approx(
        (job.finished_at - job.started_at).total_seconds()
    )
    assert entry.origin == "test"
