"""A firmware reset the host cannot read as one stops the job; the job is never replayed."""

from __future__ import annotations

import pytest

from jobs.models import Job
from printers.sample_gcode import commands_of, segments
from printers.worker.loop import PrinterWorker
from tests.conftest import job_lines, wait_for

pytestmark = [pytest.mark.django_db, pytest.mark.slow]


def executed(sim) -> int:
    """Commands the simulator ran, from its stats (the record lags up to 50 ms)."""
    return sim.stats()["executed"]


@pytest.mark.parametrize("banner", ["none", "noise"])
def test_reset_mid_job_stops_the_job_and_never_replays_it(
    sim_factory, make_printer, make_job, banner
):
    # 600 moves; the firmware resets after its 396th command, printing nothing
    # (none) or bootloader bytes glued to `start` (noise). Its next numbered line
    # brings `Resend: 1`: serving it would run the job a second time from line 1.
    text = segments(596)
    sim = sim_factory(
        "marlin", "--baud", "115200", "--time-scale", "0", "--reset-after", "396",
        "--reset-banner", banner,
    )  # fmt: skip
    printer = make_printer(port=str(sim.link), baud=115200)
    job = make_job(printer, text)
    worker = PrinterWorker(printer)
    worker.start()
    try:
        wait_for(
            lambda: Job.objects.get(pk=job.pk).state not in ("queued", "printing"),
            60, "the job to end", step=worker.tick,
        )  # fmt: skip
    finally:
        worker.stop()

    job = Job.objects.get(pk=job.pk)
    assert job.state == Job.State.FAILED, job.message
    assert "reset" in job.message and "not continued" in job.message
    wait_for(lambda: len(sim.executed()) == executed(sim), 5, "the whole record")
    ran = job_lines(sim)
    assert ran == commands_of(text)[: len(ran)], "a job line ran twice"
    assert len(ran) < len(commands_of(text))
