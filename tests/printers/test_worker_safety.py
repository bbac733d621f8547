"""Safety: emergency stop ahead of everything, resets and lost ports stop the job."""

from __future__ import annotations

import pytest

from jobs.commands import emergency_stop
from jobs.models import Job
from printers.models import Printer, ResponseLine
from printers.sample_gcode import commands_of, segments
from printers.worker.loop import PrinterWorker
from tests.conftest import job_lines, wait_for

pytestmark = pytest.mark.django_db


def job_state(job: Job) -> Job:
    return Job.objects.get(pk=job.pk)


def start_worker(printer: Printer) -> PrinterWorker:
    worker = PrinterWorker(printer)
    worker.start()
    return worker


def test_emergency_stop_overtakes_a_full_window(sim_factory, make_printer, make_job):
    # Real-time moves keep the planner full, so the window stays full too.
    sim = sim_factory("marlin", "--baud", "115200", "--time-scale", "1")
    printer = make_printer(port=str(sim.link), baud=115200, flow="buffered")
    text = segments(2000)
    job = make_job(printer, text)
    worker = start_worker(printer)
    try:
        # The planner (16 blocks) is full once 20 moves ran; then oks are held back.
        wait_for(
            lambda: len(job_lines(sim)) > 20
            and not worker.protocol.can_send("G1 X100.000 Y100.000 E0.01000"),
            30, "a full planner and a full window", step=worker.tick,
        )  # fmt: skip
        emergency_stop(printer, origin="tester")
        wait_for(
            lambda: job_state(job).state == "aborted", 10, "abort", step=worker.tick
        )
        wait_for(lambda: "M112" in sim.executed(), 5, "M112 in the record")
        worker.log.flush()
    finally:
        worker.stop()

    executed = sim.executed()
    assert executed[-1] == "M112", "nothing may run after the emergency stop"
    ran = [c for c in job_lines(sim) if c != "M112"]
    assert ran == commands_of(text)[: len(ran)]
    texts = list(
        ResponseLine.objects.filter(printer=printer, kind=1)
        .order_by("seq")
        .values_list("text", flat=True)
    )
    stop = texts.index("M112")
    sent_before = [t for t in texts[:stop] if t.startswith("N") and "M110" not in t]
    assert len(ran) < len(sent_before), "M112 overtook none of the lines in flight"
    after = [t for t in texts[stop + 1 :] if t.startswith("N")]
    assert after == [], f"job lines sent after M112: {after}"
    assert job_state(job).message == "emergency stop by tester"


def test_firmware_reset_mid_job_stops_the_job_with_a_reason(
    sim_factory, make_printer, make_job
):
    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "0")
    printer = make_printer(port=str(sim.link), baud=250000)
    text = segments(20000)
    job = make_job(printer, text)
    worker = start_worker(printer)
    try:
        wait_for(lambda: len(job_lines(sim)) > 300, 30, "300 lines", step=worker.tick)
        assert sim.control("reset") == "ok"
        wait_for(lambda: job_state(job).state == "failed", 10, "the job to stop",
                 step=worker.tick)  # fmt: skip
        for _ in range(50):
            worker.tick()
    finally:
        worker.stop()

    job = job_state(job)
    assert "reset" in job.message and "not continued" in job.message
    ran = job_lines(sim)
    assert ran == commands_of(text)[: len(ran)], "no line repeated or skipped"
    assert len(ran) < 20003


def test_port_that_disappears_is_reported_and_the_worker_reconnects(
    sim_factory, make_printer, make_job
):
    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "0")
    printer = make_printer(port=str(sim.link), baud=250000)
    job = make_job(printer, segments(20000))
    worker = start_worker(printer)
    try:
        wait_for(lambda: len(job_lines(sim)) > 300, 30, "300 lines", step=worker.tick)
        assert sim.control("close") == "ok"
        wait_for(lambda: worker.transport is None, 10, "the loss", step=worker.tick)
        worker.status.save_if_due(worker.clock(), force=True)
        printer.refresh_from_db()
        assert printer.state == Printer.State.OFFLINE
        assert "port lost" in printer.state_message
        assert sim.control("reopen") == "ok"
        wait_for(
            lambda: worker.transport is not None, 20, "a reconnect", step=worker.tick
        )
    finally:
        worker.stop()

    job = job_state(job)
    assert job.state == Job.State.INTERRUPTED
    assert "port went away" in job.message


def test_unknown_port_is_reported_and_the_worker_keeps_running(make_printer):
    printer = make_printer(port="/dev/ttyACM97")  # allowed, but not plugged in
    worker = start_worker(printer)
    try:
        for _ in range(3):
            worker.tick()
        worker.status.save_if_due(worker.clock(), force=True)
    finally:
        worker.stop()

    assert worker.transport is None
    assert worker.next_connect > 0
    texts = list(
        ResponseLine.objects.filter(printer=printer).values_list("text", flat=True)
    )
    assert any("cannot open port" in t and "retrying in" in t for t in texts)


def test_job_with_a_line_over_the_limit_fails_and_the_next_job_prints(
    sim_factory, make_printer, make_job
):
    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "0")
    printer = make_printer(port=str(sim.link), baud=250000, auto_start=True)
    bad = make_job(printer, segments(10))
    # The file changed on disk after it was checked: the protocol must refuse the line.
    bad.path.write_text("G28\nG1 X" + "1" * 120 + "\nG1 X2\n")
    good = make_job(printer, segments(10))
    worker = start_worker(printer)
    try:
        wait_for(lambda: job_state(good).state == "completed", 20, "the good job",
                 step=worker.tick)  # fmt: skip
    finally:
        worker.stop()

    bad = job_state(bad)
    assert bad.state == Job.State.FAILED
    assert bad.message.startswith("line 2:")
    assert "G1 X1111" not in " ".join(sim.executed())


def test_firmware_that_stops_answering_fails_the_job_with_a_clear_message(
    sim_factory, make_printer, make_job
):
    sim = sim_factory(
        "marlin", "--baud", "250000", "--time-scale", "0", "--keepalive", "0"
    )
    printer = make_printer(port=str(sim.link), baud=250000, ack_timeout=0.5)
    job = make_job(printer, segments(20000))
    worker = start_worker(printer)
    try:
        wait_for(lambda: len(job_lines(sim)) > 300, 30, "300 lines", step=worker.tick)
        assert sim.control("busy 60") == "ok"
        wait_for(lambda: job_state(job).state == "failed", 20, "the job to fail",
                 step=worker.tick)  # fmt: skip
    finally:
        worker.stop()

    message = job_state(job).message
    assert "no answer" in message or "did not answer" in message, message
    ran = job_lines(sim)
    assert ran == commands_of(segments(20000))[: len(ran)]


def test_grbl_emergency_stop_is_feed_hold_and_soft_reset(
    sim_factory, make_printer, make_job
):
    from jobs.commands import send_command
    from printers.models import QueuedCommand

    sim = sim_factory("grbl", "--baud", "115200", "--time-scale", "1")
    printer = make_printer(
        port=str(sim.link), baud=115200, firmware="grbl", status_interval=0.2
    )
    job = make_job(printer, segments(2000, cnc=True))
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
    finally:
        worker.stop()

    texts = list(
        ResponseLine.objects.filter(printer=printer)
        .order_by("seq")
        .values_list("text", flat=True)
    )
    hold = texts.index("<! feed hold>")
    assert texts[hold + 1].startswith("<0x18"), texts[hold : hold + 3]
    assert any(t.startswith("Grbl 1.1") for t in texts[hold:]), "no reset banner"
    assert job_state(job).message == "emergency stop by tester"
    assert QueuedCommand.objects.get(pk=heating.pk).reply.startswith("error: M108")
