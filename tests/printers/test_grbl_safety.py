"""GRBL's safety: an emergency stop, a job that stops early, a start script refused
and typed commands mid-job leave the machine stopped or untouched."""

from __future__ import annotations

import pytest

from jobs.commands import emergency_stop
from printers.models import ResponseLine
from printers.sample_gcode import commands_of, segments
from tests.conftest import job_lines, wait_for
from tests.printers.worker_helpers import (
    job_state,
    logged,
    start_worker,
    wait_until_failed,
)

pytestmark = pytest.mark.django_db


def test_grbl_emergency_stop_is_feed_hold_and_soft_reset(
    sim_factory, make_printer, make_job
):
    from jobs.commands import send_command
    from printers.models import QueuedCommand

    sim = sim_factory("grbl", "--baud", "115200", "--time-scale", "1")
    printer = make_printer(
        port=str(sim.link), baud=115200, firmware="grbl", status_interval=0.2,
        auto_start=True,
    )  # fmt: skip
    job = make_job(printer, segments(2000, cnc=True))
    after = make_job(printer, segments(20, cnc=True), name="next.gcode")
    worker = start_worker(printer)
    try:
        wait_for(lambda: len(sim.executed()) > 20, 30, "motion", step=worker.tick)
        heating = send_command(printer, "M108", origin="tester")
        emergency_stop(printer, origin="tester")
        wait_for(
            lambda: job_state(job).state == "aborted", 10, "abort", step=worker.tick
        )

        def banner() -> bool:
            worker.log.flush()
            lines = ResponseLine.objects.filter(
                printer=printer, text__startswith="Grbl"
            )
            return lines.exists()

        wait_for(banner, 10, "GRBL's banner after the soft reset", step=worker.tick)
        worker.log.flush()
        # The reset left GRBL unlocked: the stop's halt holds all the same, so the
        # next job (auto_start) does not set the machine moving again.
        worker.maybe_claim_job(worker.clock())
        assert worker.halted.startswith("emergency stop by tester")
        assert job_state(after).state == "queued"
    finally:
        worker.stop()

    texts = logged(printer)
    hold = texts.index("<! feed hold>")
    assert texts[hold + 1].startswith("<0x18"), texts[hold : hold + 3]
    assert any(t.startswith("Grbl 1.1") for t in texts[hold:]), "no reset banner"
    assert job_state(job).message == "emergency stop by tester"
    assert QueuedCommand.objects.get(pk=heating.pk).reply.startswith("error: M108")


def test_a_grbl_start_script_refused_stops_the_job_before_its_first_line(
    sim_factory, make_printer, make_job
):
    """`G1 X5` without a feed rate is GRBL's error:22: the job does not run on a
    machine its start script did not set up."""
    sim = sim_factory("grbl", "--baud", "0", "--time-scale", "0")
    printer = make_printer(
        port=str(sim.link), firmware="grbl", start_script="G21\nG1 X5"
    )
    text = "G0 X1 Y1\nG1 X2 Y2 F300\n"
    job = make_job(printer, text)
    worker = start_worker(printer)
    try:
        wait_until_failed(worker, job)
    finally:
        worker.stop()
    assert "start script failed" in job_state(job).message
    assert "G0X1Y1" not in [c.replace(" ", "") for c in sim.executed()]


def _grbl_cutting(sim_factory, make_printer, make_job, text: str):
    sim = sim_factory("grbl", "--baud", "115200", "--time-scale", "1")
    printer = make_printer(
        port=str(sim.link), baud=115200, firmware="grbl", status_interval=0.2
    )
    job = make_job(printer, text)
    worker = start_worker(printer)
    wait_for(lambda: " M3 " in f" {sim.stats()['state']} ", 30, "the spindle on",
             step=worker.tick)  # fmt: skip
    return sim, printer, job, worker


def _stopped(sim, worker) -> None:
    """GRBL reset (its buffers gone, the spindle off) and idle, nothing run since."""
    wait_for(
        lambda: " M5 " in f" {sim.stats()['state']} "
        and worker.status.fields.get("machine_status", {}).get("state") == "Idle"
        and not worker.expect_reset,
        15, "GRBL reset, its spindle off", step=worker.tick,
    )  # fmt: skip
    ran = sim.stats()["executed"]
    seen: list[object] = []

    def reports() -> bool:  # two more status reports: time for anything buffered
        report = worker.protocol.last_status
        if not seen or seen[-1] is not report:
            seen.append(report)
        return len(seen) >= 3

    wait_for(reports, 10, "two more status reports", step=worker.tick)
    assert sim.stats()["executed"] == ran, "GRBL ran on after the reset"


@pytest.mark.parametrize("how", ["aborted", "failed"])
def test_a_grbl_job_that_stops_early_stops_the_machine_and_its_spindle(
    sim_factory, make_printer, make_job, how
):
    """GRBL runs what it buffered whatever the host does next: an abort queued
    nothing ahead of it and an error:N sent a feed hold only, so the machine cut
    on (held, the spindle on, the rest of the job in its buffer for a `~`)."""
    from jobs.commands import request_action

    bad = "G0X\n" if how == "failed" else ""  # error:2, halfway
    moves = segments(400, cnc=True).splitlines(keepends=True)
    text = "M3 S12000\n" + "".join(moves[:200]) + bad + "".join(moves[200:])
    sim, printer, job, worker = _grbl_cutting(sim_factory, make_printer, make_job, text)
    try:
        if how == "aborted":
            wait_for(lambda: len(sim.executed()) > 20, 30, "motion", worker.tick)
            request_action(printer, "abort", origin="tester")
        wait_for(lambda: job_state(job).state == how, 60, how, step=worker.tick)
        _stopped(sim, worker)
        worker.log.flush()
    finally:
        worker.stop()
    texts = logged(printer)
    hold = texts.index("<! feed hold>")
    assert any(t.startswith("<0x18") for t in texts[hold:]), "no soft reset"
    assert len(job_lines(sim)) < len(commands_of(text)), "the job ran to its end"


def test_a_grbl_job_is_not_changed_under_it_by_a_typed_command(
    sim_factory, make_printer, make_job
):
    """GRBL has one modal state and one set of offsets: G91 typed mid-job made
    the job's next lines relative, $100= changed its steps/mm halfway."""
    from jobs.commands import send_command
    from printers.models import QueuedCommand

    text = "M3 S12000\n" + segments(400, cnc=True)
    sim, printer, job, worker = _grbl_cutting(sim_factory, make_printer, make_job, text)
    try:
        rows = {t: send_command(printer, t) for t in ("G91", "$100=400", "$G")}

        def answered() -> bool:
            pending = QueuedCommand.objects.filter(pk__in=[r.pk for r in rows.values()])
            return not pending.filter(state__in=("pending", "sent")).exists()

        wait_for(answered, 20, "the answers", step=worker.tick)
    finally:
        worker.stop()
    replies = {t: QueuedCommand.objects.get(pk=r.pk).reply for t, r in rows.items()}
    for typed in ("G91", "$100=400"):
        assert replies[typed].startswith(f"error: {typed!r} would change what GRBL")
    assert replies["$G"].startswith("ok")
    assert "G91" not in sim.executed() and "$100=400" not in sim.executed()


@pytest.mark.parametrize(
    ("state", "reset"),
    [("Hold:1", False), ("Hold", False), ("Run", False), ("Hold:0", True),
     ("Idle", True)],
)  # fmt: skip
def test_grbl_is_reset_once_held_or_idle_and_not_while_it_decelerates(state, reset):
    """Real GRBL reports Hold:1 while it decelerates (the simulator stops at once):
    a reset then loses its position. GRBL 0.9 says only "Hold": the 2 s bound
    decides. Either way the reset comes by the bound."""
    from types import SimpleNamespace

    from printers.protocol.grbl import GrblProtocol
    from printers.worker.emergency import (
        HOLD_SETTLE_SECONDS,
        hold_then_reset,
        reset_when_held,
    )

    worker = SimpleNamespace(
        protocol=GrblProtocol(), transport=object(), expect_reset=False,
        reset_due=None, note=lambda text: None,
    )  # fmt: skip
    hold_then_reset(worker, 10.0)
    reset_when_held(worker, 10.5, state)
    assert worker.expect_reset is reset
    reset_when_held(worker, 10.0 + HOLD_SETTLE_SECONDS)
    assert worker.expect_reset and worker.reset_due is None
    assert worker.protocol.data_to_send().startswith(b"!\x18")
