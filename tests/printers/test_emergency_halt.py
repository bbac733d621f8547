"""An emergency stop's halt lasts until an operator's reconnect: not a board that
comes back by itself, nor a worker started again."""

from __future__ import annotations

import pytest

from jobs.commands import emergency_stop, request_action
from jobs.models import Job
from printers.models import Printer, ResponseLine
from printers.worker.loop import PrinterWorker
from tests.conftest import wait_for
from tests.printers.worker_helpers import job_state, start_worker

pytestmark = pytest.mark.django_db


def test_a_worker_started_again_keeps_the_emergency_stop(
    sim_factory, make_printer, make_job
):
    """A restart (an upgrade, a crash, systemd) used to forget the halt: with
    auto_start, the next queued job started on a machine stopped in an emergency."""
    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "0")
    printer = make_printer(port=str(sim.link), baud=250000, auto_start=True)
    first = PrinterWorker(printer)
    first.start()
    try:
        wait_for(lambda: first.status.state == "idle", 10, "idle", first.tick)
        emergency_stop(printer, origin="tester")
        wait_for(lambda: first.halted, 10, "the halt", step=first.tick)
        halt = first.halted
    finally:
        first.stop()
    assert Printer.objects.get(pk=printer.pk).emergency_halt == halt

    job = make_job(printer, "G28\n")
    second = PrinterWorker(Printer.objects.get(pk=printer.pk))
    second.start()
    try:
        wait_for(lambda: second.status.state == "error", 10, "connected, halted",
                 step=second.tick)  # fmt: skip
        for _ in range(20):
            second.tick()
        second.maybe_claim_job(second.clock())
        assert second.halted == halt
        assert Job.objects.get(pk=job.pk).state == "queued"
        assert second.status.message == halt

        assert sim.control("reset") == "ok"  # the operator resets the board...
        request_action(printer, "reconnect", origin="tester")  # ...and reconnects
        wait_for(lambda: Job.objects.get(pk=job.pk).state != "queued", 20,
                 "the job to start", step=second.tick)  # fmt: skip
        second.status.save_if_due(second.clock(), force=True)
        assert Printer.objects.get(pk=printer.pk).emergency_halt == ""
    finally:
        second.stop()


def test_an_emergency_stop_is_ended_by_an_operator_not_by_the_board_coming_back(
    sim_factory, make_printer, make_job
):
    """A board reset (its button, a power blip) or a port that came back by itself
    is no one saying the machine is safe again: with auto_start, the next job
    started on it. Only the operator's reconnect ends the stop."""
    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "0")
    printer = make_printer(port=str(sim.link), baud=250000, auto_start=True)
    worker = start_worker(printer)
    try:
        wait_for(lambda: worker.status.state == "idle", 10, "idle", worker.tick)
        emergency_stop(printer, origin="tester")
        wait_for(lambda: worker.halted, 10, "the halt", step=worker.tick)
        job = make_job(printer, "G28\n")

        def starts() -> int:  # Marlin's boot banner
            worker.log.flush()
            return ResponseLine.objects.filter(printer=printer, text="start").count()

        before = starts()
        assert sim.control("reset") == "ok"  # the board comes back by itself
        wait_for(lambda: starts() > before, 10, "the board's reset", worker.tick)
        worker.port_lost("unplugged")  # and the port, after its backoff
        wait_for(lambda: worker.transport is not None, 10, "the port back",
                 step=worker.tick)  # fmt: skip
        worker.maybe_claim_job(worker.clock())
        assert worker.halted.startswith("emergency stop by tester")
        assert job_state(job).state == "queued"

        request_action(printer, "reconnect", origin="tester")
        wait_for(lambda: job_state(job).state != "queued", 20, "the job to start",
                 step=worker.tick)  # fmt: skip
    finally:
        worker.stop()
