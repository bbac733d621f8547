"""An emergency stop's halt outlives its worker: only an operator's reconnect ends it."""

from __future__ import annotations

import pytest

from jobs.commands import emergency_stop, request_action
from jobs.models import Job
from printers.models import Printer
from printers.worker.loop import PrinterWorker
from tests.conftest import wait_for

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
