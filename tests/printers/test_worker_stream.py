"""Whole files streamed by the worker to simulators over real ptys: nothing lost or repeated."""

from __future__ import annotations

import pytest

from jobs.models import Job
from printers.sample_gcode import commands_of, segments
from printers.worker.loop import PrinterWorker
from tests.conftest import job_lines, wait_for
from tests.printers.stream_checks import assert_streamed_exactly, run_job, sim_stats

pytestmark = [pytest.mark.django_db, pytest.mark.slow]


@pytest.mark.parametrize("corrupt", ["0.01", "0.05"])
def test_marlin_job_survives_corrupted_lines_without_loss_or_repeat(
    sim_factory, make_printer, make_job, corrupt
):
    text = segments(2500)  # 25 to 125 corrupted lines, each resent
    sim = sim_factory(
        "marlin", "--baud", "115200", "--time-scale", "0", "--corrupt", corrupt,
        "--seed", "7",
    )  # fmt: skip
    printer = make_printer(port=str(sim.link), baud=115200, flow="buffered")
    job = make_job(printer, text)
    worker = PrinterWorker(printer)

    job = run_job(worker, job, timeout=600)

    assert job.state == Job.State.COMPLETED, job.message
    assert job.lines_acked == job.line_count == 2503
    assert_streamed_exactly(sim, text)
    assert worker.protocol.resends > 10


def test_grbl_job_streams_every_line_once_in_order(sim_factory, make_printer, make_job):
    text = segments(5000, cnc=True)
    sim = sim_factory("grbl", "--baud", "115200", "--time-scale", "0")
    printer = make_printer(
        port=str(sim.link), baud=115200, firmware="grbl", status_interval=0.2
    )
    job = make_job(printer, text)
    worker = PrinterWorker(printer)

    job = run_job(worker, job, timeout=600)

    assert job.state == Job.State.COMPLETED, job.message
    wait_for(lambda: len(job_lines(sim)) >= 5004, 10, "the record")
    executed = [c.replace(" ", "") for c in job_lines(sim)]
    assert executed == [c.replace(" ", "") for c in commands_of(text)]
    assert sim_stats(sim)["dropped_bytes"] == 0
