"""Marlin host action commands, host prompts and M600, worker against the simulator."""

from __future__ import annotations

import time

import pytest

from jobs.commands import request_action
from jobs.models import Job
from printers.models import Printer, QueuedCommand, ResponseLine
from printers.sample_gcode import segments
from printers.worker.loop import PrinterWorker
from tests.conftest import job_lines, wait_for
from tests.printers.stream_checks import assert_streamed_exactly

pytestmark = pytest.mark.django_db

PAUSE_SCRIPT = "M117 pause script"
RESUME_SCRIPT = "M117 resume script"


def job_state(job: Job) -> str:
    return Job.objects.get(pk=job.pk).state


def started(printer: Printer) -> PrinterWorker:
    worker = PrinterWorker(printer)
    worker.start()
    return worker


def with_m600(count: int, at: int) -> str:
    lines = segments(count).splitlines()
    return "\n".join([*lines[:at], "M600", *lines[at:]]) + "\n"


def prompt_of(printer: Printer) -> dict | None:
    printer.refresh_from_db()
    return (printer.machine_status or {}).get("prompt")


def tick_for(worker: PrinterWorker, seconds: float) -> None:
    """Keep the worker running for *seconds* (the user taking their time)."""
    until = time.monotonic() + seconds
    wait_for(lambda: time.monotonic() >= until, seconds + 5, "time", step=worker.tick)


def test_m600_waits_for_the_user_longer_than_the_ack_timeout_and_completes(
    sim_factory, make_printer, make_job
):
    sim = sim_factory("marlin", "--time-scale", "0", "--keepalive", "0.5")
    printer = make_printer(
        port=str(sim.link), ack_timeout=1.0, busy_timeout=2.0, flow="buffered"
    )
    text = with_m600(200, at=100)
    job = make_job(printer, text)
    worker = started(printer)
    try:
        wait_for(lambda: prompt_of(printer) is not None, 30, "the prompt",
                 step=worker.tick)  # fmt: skip
        assert prompt_of(printer) == {
            "message": "Nozzle Parked",
            "choices": ["Continue"],
            "answerable": True,
        }
        printer.refresh_from_db()
        assert printer.state == "paused"  # //action:paused: the printer parked
        assert "waiting for the user: Nozzle Parked — Continue" in printer.state_message
        tick_for(worker, 4.0)  # longer than ack_timeout and busy_timeout
        assert job_state(job) == "paused"
        row = request_action(printer, "prompt:0", origin="tester")
        wait_for(lambda: job_state(job) == "completed", 30, "the job to complete",
                 step=worker.tick)  # fmt: skip
        worker.log.flush()
    finally:
        worker.stop()
    row.refresh_from_db()
    assert row.reply == "ok: M876 S0 sent"
    assert "M876 S0" in sim.executed()
    assert prompt_of(printer) is None
    assert_streamed_exactly(sim, text)
    assert PAUSE_SCRIPT not in sim.executed()


def test_paused_for_user_outlasts_a_busy_timeout_shorter_than_the_keepalive(
    sim_factory, make_printer, make_job
):
    # Marlin's default keepalive (2 s) is longer than this busy_timeout: for
    # `busy: processing` that is a timeout between two keepalives; for a printer
    # waiting for the user it must not be (no deadline until the next ok).
    sim = sim_factory("marlin", "--time-scale", "0", "--keepalive", "2")
    printer = make_printer(
        port=str(sim.link), ack_timeout=3.0, busy_timeout=1.0, flow="buffered"
    )
    text = with_m600(40, at=20)
    job = make_job(printer, text)
    worker = started(printer)
    try:
        wait_for(lambda: prompt_of(printer) is not None, 30, "the prompt",
                 step=worker.tick)  # fmt: skip
        tick_for(worker, 7.0)  # three keepalives, each more than busy_timeout apart
        assert job_state(job) == "paused"
        request_action(printer, "prompt:0")
        wait_for(lambda: job_state(job) == "completed", 30, "the job to complete",
                 step=worker.tick)  # fmt: skip
    finally:
        worker.stop()
    assert worker.protocol.timeouts == 0
    assert_streamed_exactly(sim, text)


def test_answering_when_nothing_is_asked_is_an_error(sim_factory, make_printer):
    sim = sim_factory("marlin", "--time-scale", "0")
    printer = make_printer(port=str(sim.link))
    worker = started(printer)
    try:
        wait_for(lambda: worker.emergency_parser is not None, 10, "M115",
                 step=worker.tick)  # fmt: skip
        row = request_action(printer, "prompt:0")
        wait_for(lambda: QueuedCommand.objects.get(pk=row.pk).state == "failed", 10,
                 "the answer", step=worker.tick)  # fmt: skip
    finally:
        worker.stop()
    row.refresh_from_db()
    assert row.reply == "error: the printer is not asking anything now"


def scripted_printer(sim_factory, make_printer) -> tuple[object, Printer]:
    sim = sim_factory("marlin", "--time-scale", "1")
    printer = make_printer(
        port=str(sim.link), pause_script=PAUSE_SCRIPT, resume_script=RESUME_SCRIPT,
    )  # fmt: skip
    return sim, printer


def test_action_cancel_from_the_firmware_aborts_the_job(
    sim_factory, make_printer, make_job
):
    sim, printer = scripted_printer(sim_factory, make_printer)
    job = make_job(printer, segments(3000))
    worker = started(printer)
    try:
        wait_for(lambda: len(job_lines(sim)) > 10, 30, "the job", step=worker.tick)
        assert sim.control("action cancel") == "ok"
        wait_for(lambda: job_state(job) == "aborted", 10, "the abort", step=worker.tick)
    finally:
        worker.stop()
    assert "//action:cancel" in Job.objects.get(pk=job.pk).message


def test_action_paused_and_resumed_run_no_scripts(sim_factory, make_printer, make_job):
    sim, printer = scripted_printer(sim_factory, make_printer)
    job = make_job(printer, segments(3000))
    worker = started(printer)
    try:
        wait_for(lambda: len(job_lines(sim)) > 10, 30, "the job", step=worker.tick)
        assert sim.control("action paused") == "ok"
        wait_for(lambda: job_state(job) == "paused", 10, "the pause", step=worker.tick)
        assert sim.control("action resumed") == "ok"
        wait_for(lambda: job_state(job) == "printing", 10, "the resume",
                 step=worker.tick)  # fmt: skip
        wait_for(lambda: len(job_lines(sim)) > 40, 30, "more lines", step=worker.tick)
    finally:
        worker.stop()
    assert PAUSE_SCRIPT not in sim.executed()
    assert RESUME_SCRIPT not in sim.executed()


def test_action_pause_runs_the_pause_script(sim_factory, make_printer, make_job):
    sim, printer = scripted_printer(sim_factory, make_printer)
    job = make_job(printer, segments(3000))
    worker = started(printer)
    try:
        wait_for(lambda: len(job_lines(sim)) > 10, 30, "the job", step=worker.tick)
        assert sim.control("action pause") == "ok"
        wait_for(lambda: job_state(job) == "paused", 10, "the pause", step=worker.tick)
        wait_for(lambda: PAUSE_SCRIPT in sim.executed(), 10, "the pause script",
                 step=worker.tick)  # fmt: skip
    finally:
        worker.stop()


def test_action_disconnect_closes_the_port_until_a_reconnect(sim_factory, make_printer):
    sim = sim_factory("marlin", "--time-scale", "0")
    printer = make_printer(port=str(sim.link))
    worker = started(printer)
    try:
        wait_for(lambda: worker.emergency_parser is not None, 10, "M115",
                 step=worker.tick)  # fmt: skip
        assert sim.control("action disconnect") == "ok"
        wait_for(lambda: worker.transport is None, 10, "the port to close",
                 step=worker.tick)  # fmt: skip
        tick_for(worker, 1.0)
        assert worker.transport is None, "it must stay offline"
        request_action(printer, "reconnect")
        wait_for(lambda: worker.transport is not None, 10, "the reconnect",
                 step=worker.tick)  # fmt: skip
        worker.log.flush()
    finally:
        worker.stop()
    texts = ResponseLine.objects.filter(printer=printer).values_list("text", flat=True)
    assert any("//action:disconnect" in t for t in texts if t.startswith("[printhost]"))


def test_without_the_emergency_parser_the_prompt_says_to_use_the_display(
    sim_factory, make_printer, make_job
):
    sim = sim_factory("marlin", "--time-scale", "0", "--no-emergency-parser")
    printer = make_printer(port=str(sim.link), ack_timeout=1.0, busy_timeout=2.0)
    text = with_m600(20, at=10)
    job = make_job(printer, text)
    worker = started(printer)
    try:
        wait_for(lambda: prompt_of(printer) is not None, 30, "the prompt",
                 step=worker.tick)  # fmt: skip
        assert prompt_of(printer)["answerable"] is False
        printer.refresh_from_db()
        assert "answer on the printer's display" in printer.state_message
        row = request_action(printer, "prompt:0")
        wait_for(lambda: QueuedCommand.objects.get(pk=row.pk).state == "done", 10,
                 "the answer", step=worker.tick)  # fmt: skip
        row.refresh_from_db()
        assert "answer on the printer's display" in row.reply
        tick_for(worker, 2.0)
        assert job_state(job) == "paused", "M876 cannot reach a parked firmware"
        assert sim.control("click") == "ok"  # the printer's own display
        wait_for(lambda: job_state(job) == "completed", 30, "the job to complete",
                 step=worker.tick)  # fmt: skip
    finally:
        worker.stop()
    assert_streamed_exactly(sim, text)


def test_a_notification_from_the_printer_goes_to_the_log(sim_factory, make_printer):
    sim = sim_factory("marlin", "--time-scale", "0")
    printer = make_printer(port=str(sim.link))
    worker = started(printer)
    try:
        wait_for(lambda: worker.emergency_parser is not None, 10, "M115",
                 step=worker.tick)  # fmt: skip
        assert sim.control("action notification Filament runout") == "ok"
        wait_for(
            lambda: worker.log.flush() is None and ResponseLine.objects.filter(
                printer=printer, text="[printhost] printer says: Filament runout"
            ).exists(),
            10, "the note", step=worker.tick,
        )  # fmt: skip
    finally:
        worker.stop()
    assert (
        sim.control("click") == "error: click: the printer is not waiting for the user"
    )
