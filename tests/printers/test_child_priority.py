"""runhost's children: printing comes first, what can wait runs nicer."""

from __future__ import annotations

import os
import sys

import pytest

from printers.supervisor import NICENESS, Child


@pytest.mark.parametrize(
    ("name", "added"),
    [("worker:mk3", 0), ("sim:mk3", 0), ("daphne", 5), ("celery", 10), ("fetcher", 10)],
)
def test_work_that_can_wait_runs_nicer_than_the_printers(name, added):
    child = Child(name, [sys.executable, "-c", "import signal; signal.pause()"])
    child.start(0.0)
    try:
        mine = os.getpriority(os.PRIO_PROCESS, 0)
        assert os.getpriority(os.PRIO_PROCESS, child.process.pid) == min(
            19, mine + added
        )
        assert NICENESS.get(name, 0) == added
    finally:
        child.process.kill()
        child.process.wait()
