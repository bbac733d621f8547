"""An aborted or failed Marlin job stops the moves its planner still holds: M410
(quickstop) goes out ahead of the abort script (Reactions.stop_motion_after_error).

The simulator times its moves as a firmware does, in real time: each move of the
job takes 2 s, and Marlin acknowledges a move when it enters its 16-block planner,
so at the abort half a minute of motion is planned, and a few more moves wait in
its command buffer (M410 drops the planner's moves, not the commands Marlin has
received and not yet planned). The abort script waits for the planner (M400)
before its message: it runs within the test's bound only if the planned moves
were dropped.
"""

from __future__ import annotations

import pytest

from jobs.commands import request_action
from tests.conftest import job_lines, wait_for
from tests.printers.worker_helpers import job_state, start_worker

pytestmark = pytest.mark.django_db

#: 60 moves of 100 mm at 50 mm/s: two minutes of motion.
SLOW_MOVES = "G1 X100 F3000\nG1 X0 F3000\n" * 30
AFTER = "M117 after the planner"


def test_an_aborted_marlin_job_drops_its_planned_moves_before_the_abort_script(
    sim_factory, make_printer, make_job
):
    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "1")
    printer = make_printer(
        port=str(sim.link), baud=250000, abort_script=f"M400\n{AFTER}"
    )
    job = make_job(printer, SLOW_MOVES)
    worker = start_worker(printer)
    try:
        wait_for(
            lambda: len(job_lines(sim)) >= 16, 30, "the planner full", step=worker.tick
        )
        request_action(printer, "abort", origin="test")
        wait_for(lambda: job_state(job).state == "aborted", 10, "the abort",
                 step=worker.tick)  # fmt: skip
        # Without the quickstop, M400 would wait for minutes of planned moves.
        wait_for(lambda: AFTER in sim.executed(), 20, f"the abort script past M400 {sim.executed()[-8:]}",
                 step=worker.tick)  # fmt: skip
    finally:
        worker.stop()
    ran = sim.executed()
    assert ran.index("M410") < ran.index("M400")
    assert len(job_lines(sim)) < 60
