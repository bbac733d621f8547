"""A Marlin printer with `quickstop_on_abort` drops the moves its planner still holds
when a job is aborted: M410 (quickstop) goes out ahead of the abort script
(Reactions.stop_motion_after_error). Off (the default) nothing is added: the planned
moves run out, then the abort script, as OctoPrint does.

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
from django.core.exceptions import ValidationError

from jobs.commands import request_action
from printers.models import Printer, ResponseLine
from tests.conftest import job_lines, wait_for
from tests.printers.worker_helpers import job_state, start_worker

pytestmark = pytest.mark.django_db

#: 60 moves of 100 mm at 50 mm/s: two minutes of motion.
SLOW_MOVES = "G1 X100 F3000\nG1 X0 F3000\n" * 30
AFTER = "M117 after the planner"


def _abort_with_a_full_planner(sim, printer, job) -> list[str]:
    """Abort the job once Marlin's planner is full; what the simulator ran by the
    time the job shows aborted and the worker stopped."""
    worker = start_worker(printer)
    try:
        wait_for(
            lambda: len(job_lines(sim)) >= 16, 30, "the planner full", step=worker.tick
        )
        request_action(printer, "abort", origin="test")
        wait_for(lambda: job_state(job).state == "aborted", 10, "the abort",
                 step=worker.tick)  # fmt: skip
        if printer.quickstop_on_abort:
            # Without the quickstop, M400 would wait for minutes of planned moves.
            wait_for(lambda: AFTER in sim.executed(), 20, "the abort script past M400",
                     step=worker.tick)  # fmt: skip
        else:
            for _ in range(50):  # turns enough for an M410 to have gone out
                worker.tick()
    finally:
        worker.stop()
    return sim.executed()


def test_a_quickstop_printer_drops_its_planned_moves_before_the_abort_script(
    sim_factory, make_printer, make_job
):
    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "1")
    printer = make_printer(
        port=str(sim.link), baud=250000, abort_script=f"M400\n{AFTER}",
        quickstop_on_abort=True,
    )  # fmt: skip
    ran = _abort_with_a_full_planner(sim, printer, make_job(printer, SLOW_MOVES))
    assert ran.index("M410") < ran.index("M400")
    assert len(job_lines(sim)) < 60


def test_a_firmware_without_m410_gets_a_note_that_the_quickstop_did_nothing(
    sim_factory, make_printer, make_job
):
    """Prusa-Firmware on a MK3 has no M410: it answers `Unknown command` and its
    planner runs on, so the operator is told rather than left to trust it."""
    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "1",
                      "--dialect", "prusa")  # fmt: skip
    printer = make_printer(
        port=str(sim.link), baud=250000, abort_script=AFTER, quickstop_on_abort=True
    )
    make_job(printer, SLOW_MOVES)
    worker = start_worker(printer)
    try:
        wait_for(
            lambda: len(job_lines(sim)) >= 16, 30, "the planner full", step=worker.tick
        )
        request_action(printer, "abort", origin="test")
        noted = ResponseLine.objects.filter(
            printer=printer, text__contains="the firmware does not know M410"
        )
        wait_for(noted.exists, 10, "the note", step=worker.tick)
    finally:
        worker.stop()
    assert ResponseLine.objects.filter(
        printer=printer, text='echo:Unknown command: "M410"'
    ).exists()


def test_by_default_an_abort_sends_no_quickstop(sim_factory, make_printer, make_job):
    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "1")
    printer = make_printer(
        port=str(sim.link), baud=250000, abort_script=f"M400\n{AFTER}"
    )
    ran = _abort_with_a_full_planner(sim, printer, make_job(printer, SLOW_MOVES))
    assert "M410" not in ran
    assert AFTER not in ran  # the planned moves are still running out


def test_a_firmware_error_mid_job_quickstops_once(sim_factory, make_printer, make_job):
    """The error stops the stream at once and its end asks again: one M410, or a
    second could cut the abort script's moves short."""
    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "1")
    printer = make_printer(port=str(sim.link), baud=250000, quickstop_on_abort=True)
    job = make_job(printer, SLOW_MOVES)
    worker = start_worker(printer)
    try:
        wait_for(
            lambda: len(job_lines(sim)) >= 16, 30, "the planner full", step=worker.tick
        )
        assert sim.control("say Error:Probing failed") == "ok"
        wait_for(lambda: job_state(job).state == "failed", 10, "the failure",
                 step=worker.tick)  # fmt: skip
        wait_for(lambda: "M410" in sim.executed(), 10, "the quickstop",
                 step=worker.tick)  # fmt: skip
        for _ in range(50):  # turns enough for a second one to have gone out
            worker.tick()
    finally:
        worker.stop()
    assert sim.executed().count("M410") == 1
    assert "Probing failed" in job_state(job).message


@pytest.mark.parametrize("firmware", ["grbl", "reprap", "repetier"])
def test_the_quickstop_is_refused_for_firmware_other_than_marlin(firmware):
    printer = Printer(
        name="X", slug="x", port="/dev/null", firmware=firmware, quickstop_on_abort=True
    )
    with pytest.raises(ValidationError, match="Marlin's M410"):
        printer.full_clean()


def test_an_admin_turns_the_quickstop_on_for_marlin_and_not_for_grbl(
    make_printer, admin_client
):
    marlin = make_printer()
    grbl = make_printer(firmware="grbl")
    for printer, status in ((marlin, 200), (grbl, 400)):
        answer = admin_client.patch(
            f"/printer/config/{printer.slug}",
            {"quickstop_on_abort": True},
            content_type="application/json",
        )
        assert answer.status_code == status, answer.content
    assert Printer.objects.get(pk=marlin.pk).quickstop_on_abort
    assert not Printer.objects.get(pk=grbl.pk).quickstop_on_abort
    assert "Marlin's M410" in answer.json()["error"]
