"""GRBL's abort script runs after the soft reset that stops an aborted job."""

from __future__ import annotations

import pytest

from jobs.commands import request_action
from jobs.models import Job
from printers.sample_gcode import segments
from printers.worker.loop import PrinterWorker
from tests.conftest import wait_for

pytestmark = pytest.mark.django_db


def test_the_abort_script_runs_after_the_reset_not_into_it(
    sim_factory, make_printer, make_job
):
    """Sent at the abort, the script's lines sat in GRBL's buffer behind the job's
    and the reset emptied them with the rest: its Z lift never ran, and the tool
    stayed down in the work."""
    sim = sim_factory("grbl", "--baud", "115200", "--time-scale", "1")
    printer = make_printer(
        port=str(sim.link), baud=115200, firmware="grbl", status_interval=0.2,
        abort_script="G0 Z12\nG0 X0 Y0",
    )  # fmt: skip
    job = make_job(printer, "M3 S12000\nG1 Z-1 F600\n" + segments(400, cnc=True))
    worker = PrinterWorker(printer)
    worker.start()
    try:
        wait_for(lambda: len(sim.executed()) > 20, 30, "cutting", step=worker.tick)
        request_action(printer, "abort", origin="tester")
        wait_for(lambda: Job.objects.get(pk=job.pk).state == "aborted", 20,
                 "the abort", step=worker.tick)  # fmt: skip
        wait_for(lambda: "G0X0Y0" in sim.executed(), 20, "the abort script",
                 step=worker.tick)  # fmt: skip
    finally:
        worker.stop()
    executed = sim.executed()
    assert executed[-2:] == ["G0Z12", "G0X0Y0"]
    assert " M5 " in f" {sim.stats()['state']} "  # the reset stopped the spindle
    assert sim.stats()["state"].split()[:3] == ["0.0000", "0.0000", "12.0000"]
