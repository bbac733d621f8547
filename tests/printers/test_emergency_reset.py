"""Emergency stop on stock Marlin (no emergency parser): M112, then a DTR reset.

The simulator is reached over RFC 2217 (`rfc2217://`), which carries DTR: a pulse
resets the simulated board (buffers and planner dropped, `start` printed).
"""

from __future__ import annotations

import time

import pytest

from jobs.commands import emergency_stop
from jobs.models import Job
from printers.models import Printer, QueuedCommand, ResponseLine
from printers.worker.loop import PrinterWorker
from tests.conftest import job_lines, wait_for

pytestmark = pytest.mark.django_db

#: Each move is 20 mm at 10 mm/s: two seconds of real motion.
SLOW_MOVES = "G21\nG90\nM83\n" + "".join(
    f"G1 X{20 * (i % 2) + 100} Y100 E0.5 F600\n" for i in range(200)
)

#: Half-second moves: where only the order matters, not how long a move takes.
QUICK_MOVES = "G21\nG90\nM83\n" + "".join(
    f"G1 X{5 * (i % 2) + 5} Y0 E0.5 F600\n" for i in range(200)
)


def _printer_on_rfc2217(settings, sim_factory, make_printer, *parser: str) -> tuple:
    sim = sim_factory("marlin", "--time-scale", "1", "--tcp", "127.0.0.1:0", *parser)
    # A network port is opened only to a listed host (printers/ports.py).
    settings.PRINTHOST_PORT_HOSTS = [sim.tcp]
    printer = make_printer(port=f"rfc2217://{sim.tcp}", baud=115200)
    worker = PrinterWorker(printer)
    worker.start()
    return sim, printer, worker


def _planner_full(sim, worker: PrinterWorker) -> None:
    wait_for(
        lambda: len(job_lines(sim)) >= 19  # G21 G90 M83 and 16 planner blocks
        and not worker.protocol.can_send("G1 X100 Y100 E0.5 F600"),
        60, "a full planner, a full command queue and a full window",
        step=worker.tick,
    )  # fmt: skip


def _notes(printer: Printer) -> list[str]:
    return list(
        ResponseLine.objects.filter(printer=printer, kind=8)
        .order_by("seq")
        .values_list("text", flat=True)
    )


def test_emergency_stop_without_parser_resets_the_board_by_dtr(
    settings, sim_factory, make_printer, make_job
):
    sim, printer, worker = _printer_on_rfc2217(
        settings, sim_factory, make_printer, "--no-emergency-parser"
    )
    job = make_job(printer, SLOW_MOVES)
    try:
        _planner_full(sim, worker)
        assert worker.emergency_parser is False
        accepted_before = len(job_lines(sim))
        start = time.monotonic()
        row = emergency_stop(printer, origin="tester")
        wait_for(
            lambda: worker.halted and not worker.expect_reset, 10,
            "the board's reset banner after the DTR pulse", step=worker.tick,
        )  # fmt: skip
        elapsed = time.monotonic() - start
        worker.log.flush()
        shown = (worker.status.state, worker.status.message)
    finally:
        worker.stop()

    accepted_after = len([c for c in job_lines(sim) if c != "M112"])
    print(
        f"emergency request to board reset: {elapsed * 1000:.0f} ms; "
        f"job commands accepted after the request: {accepted_after - accepted_before}"
    )
    assert elapsed < 1.0, f"the reset took {elapsed:.2f} s"
    # A move takes 2 s: at most the one finishing as the request came was replaced.
    assert accepted_after - accepted_before <= 1
    assert "M112" not in sim.executed(), "the reset dropped M112 with the buffers"
    reply = QueuedCommand.objects.get(pk=row.pk).reply
    assert "board reset by a DTR pulse" in reply
    assert "no emergency parser" in reply
    assert any("board reset by a DTR pulse" in n for n in _notes(printer))
    assert Job.objects.get(pk=job.pk).state == Job.State.ABORTED
    assert shown[0] == Printer.State.ERROR
    assert "emergency stop by tester: M112 sent and the board reset" in shown[1]


def test_emergency_stop_with_parser_does_not_reset_the_board(
    settings, sim_factory, make_printer, make_job
):
    sim, printer, worker = _printer_on_rfc2217(settings, sim_factory, make_printer)
    make_job(printer, SLOW_MOVES)
    try:
        _planner_full(sim, worker)
        assert worker.emergency_parser is True
        row = emergency_stop(printer, origin="tester")
        wait_for(
            lambda: QueuedCommand.objects.get(pk=row.pk).reply, 10, "the reply",
            step=worker.tick,
        )  # fmt: skip
        wait_for(lambda: "M112" in sim.executed(), 5, "M112 in the record")
        wait_for(lambda: worker.halted, 5, "the firmware's halt", step=worker.tick)
        worker.log.flush()
    finally:
        worker.stop()

    assert sim.executed()[-1] == "M112"
    reply = QueuedCommand.objects.get(pk=row.pk).reply
    assert "emergency parser acts on it at once" in reply
    assert not any(
        "DTR" in t for t in ResponseLine.objects.values_list("text", flat=True)
    )
    assert not any(t == "start" for t in _notes(printer))


def test_emergency_stop_on_a_port_without_dtr_says_the_stop_waits_in_the_queue(
    sim_factory, make_printer, make_job
):
    sim = sim_factory("marlin", "--time-scale", "1", "--no-emergency-parser")
    printer = make_printer(port=str(sim.link), baud=115200)
    worker = PrinterWorker(printer)
    worker.start()
    make_job(printer, QUICK_MOVES)
    try:
        _planner_full(sim, worker)
        row = emergency_stop(printer, origin="tester")
        wait_for(
            lambda: QueuedCommand.objects.get(pk=row.pk).reply, 10, "the reply",
            step=worker.tick,
        )  # fmt: skip
        wait_for(lambda: "M112" in sim.executed(), 30, "M112 to reach the firmware",
                 step=worker.tick)  # fmt: skip
        worker.log.flush()
    finally:
        worker.stop()

    reply = QueuedCommand.objects.get(pk=row.pk).reply
    assert "waits behind the commands the firmware already buffered" in reply
    assert "could not be reset" in reply
    assert any("could not be reset" in n for n in _notes(printer))
