"""Shared checks of the stream tests: run a job to its end, compare the record, RX drops."""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING

from jobs.models import Job
from printers.sample_gcode import commands_of
from printers.worker.loop import PrinterWorker
from tests.conftest import job_lines, wait_for

if TYPE_CHECKING:
    from tests.conftest import Sim

#: What a printer row gets when a user adds one and changes nothing that matters
#: here (printers/models.py): flow auto, ADVANCED_OK unknown, temperature polling on.
USER_DEFAULTS = {
    "flow": "auto",
    "checksums": "printing",
    "temperature_interval": 2.0,
    "ack_timeout": 10.0,
    "busy_timeout": 30.0,
}


def sim_stats(sim: Sim) -> dict[str, object]:
    """The simulator's counters (executed commands, dropped RX bytes, faults)."""
    return sim.stats()


def run_job(worker: PrinterWorker, job: Job, timeout: float) -> Job:
    """Start *worker*, tick it until *job* ends (bounded), stop it; the job afresh."""
    worker.start()
    try:
        wait_for(
            lambda: Job.objects.get(pk=job.pk).state not in ("queued", "printing"),
            timeout,
            f"job {job.pk} to end",
            step=worker.tick,
        )
    finally:
        worker.stop()
    return Job.objects.get(pk=job.pk)


def assert_streamed_exactly(sim: Sim, text: str) -> None:
    """The firmware ran every line of *text* once, in order, and lost no RX byte.

    A byte the simulator's RX ring dropped means the host overran the firmware:
    the stream survived by luck (a resend), so the test fails anyway.
    """
    expected = commands_of(text)
    # Marlin acknowledges a move once it is in the planner, before it runs: the job
    # can be complete a moment before the firmware ran its last moves. A line that
    # was lost never comes, and the comparison below says which.
    with contextlib.suppress(AssertionError):
        wait_for(lambda: len(job_lines(sim)) >= len(expected), 5, "the last moves")
    ran = job_lines(sim)
    at = next(
        (i for i, (a, b) in enumerate(zip(ran, expected, strict=False)) if a != b),
        min(len(ran), len(expected)),
    )
    assert ran == expected, (
        f"a line was lost, repeated or reordered: {len(ran)} ran of "
        f"{len(expected)}; first difference at {at}: {ran[at : at + 2]} instead of "
        f"{expected[at : at + 2]}"
    )
    assert sim_stats(sim)["dropped_bytes"] == 0, "the firmware's RX buffer overflowed"
