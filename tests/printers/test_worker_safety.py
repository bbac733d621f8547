"""Safety: emergency stop ahead of everything, resets and lost ports stop the job."""

from __future__ import annotations

import time

import pytest

from jobs.commands import emergency_stop
from jobs.models import Job
from printers.models import Printer, ResponseLine
from printers.sample_gcode import commands_of, segments
from tests.conftest import job_lines, wait_for
from tests.printers.worker_helpers import (
    job_state,
    logged,
    start_worker,
    wait_until_failed,
)

pytestmark = pytest.mark.django_db


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
    texts = logged(printer, kind=1)
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


def test_a_heater_fault_worded_with_a_degree_sign_stops_the_job(
    sim_factory, make_printer, make_job
):
    """RepRapFirmware words heater faults with a degree sign: a readable error, not
    line noise to be recovered from (which sent its lines again)."""
    sim = sim_factory(
        "marlin", "--baud", "115200", "--time-scale", "1",
        "--dialect", "reprapfirmware",
    )  # fmt: skip
    printer = make_printer(port=str(sim.link), baud=115200)
    job = make_job(printer, segments(2000))
    worker = start_worker(printer)
    fault = (
        "Error: Heater 1 fault: temperature rising much more slowly than the "
        "expected 1.5°C/sec"
    )
    try:
        wait_for(lambda: len(job_lines(sim)) > 20, 30, "motion", step=worker.tick)
        assert sim.control(f"say {fault}") == "ok"
        wait_until_failed(worker, job)
    finally:
        worker.stop()
    assert "Heater 1 fault" in job_state(job).message


class ScriptedMarlin:
    """The worker's port: a Marlin that answers each line `ok`, and a numbered line
    in `script` with the bytes given there instead."""

    def __init__(self, script: dict[int, bytes]) -> None:
        self.script = script
        self.replies: list[bytes] = []
        self.written: list[bytes] = []
        #: How many lines were written when the worker read `mark`.
        self.read_mark_at: int | None = None
        self.mark = b"Temperature reading fault"
        self.woken = False

    def read(self, timeout: float, *, wake: int | None = None) -> bytes:
        data, self.replies = b"".join(self.replies), []
        if self.mark in data and self.read_mark_at is None:
            self.read_mark_at = len(self.written)
        return data

    def read_waiting(self) -> bytes:
        return self.read(0.0)

    def write(self, data: bytes) -> None:
        import re

        for line in data.splitlines():
            self.written.append(line)
            number = re.match(rb"N(\d+) ", line)
            if b"M115" in line:
                self.replies.append(b"FIRMWARE_NAME:Marlin 2.1.2\n")
            if number and int(number[1]) in self.script:
                self.replies.append(self.script.pop(int(number[1])))
            else:
                self.replies.append(b"ok\n")

    def close(self) -> None:
        pass

    def pulse_dtr(self) -> str:
        return "no DTR line"


def opens(monkeypatch: pytest.MonkeyPatch, firmware: ScriptedMarlin) -> None:
    """The worker opens *firmware* as its printer's port."""
    from printers.worker import port

    monkeypatch.setattr(
        port, "SerialTransport",
        type("Scripted", (), {"open": staticmethod(lambda url, baud: firmware)}),
    )  # fmt: skip


def test_a_firmware_error_while_a_resend_waits_sends_nothing_more_of_the_job(
    monkeypatch, make_printer, make_job
):
    """The job fails, and the lines the firmware asked for again stay unsent too."""
    firmware = ScriptedMarlin({
        10: b"Error:Line Number is not Last Line Number+1, Last Line: 8\n"
            b"Resend: 9\nok\n"
            b"Error: Temperature reading fault on heater 1: sensor open circuit\n",
    })  # fmt: skip
    opens(monkeypatch, firmware)
    printer = make_printer(port="/dev/ttyScripted", flow="buffered")
    job = make_job(printer, "".join(f"G1 X{i} Y1 F3000\n" for i in range(60)))
    worker = start_worker(printer)
    worker.pacer.byte_time = 0.0  # answered at once: nothing to pace
    try:
        wait_until_failed(worker, job)
        # Turns for as long as a drain before the resend takes (R1), and more.
        until = time.monotonic() + 1.0
        while time.monotonic() < until:
            worker.tick()
    finally:
        worker.stop()
    assert "Temperature reading fault" in job_state(job).message
    assert firmware.read_mark_at is not None
    after = [w for w in firmware.written[firmware.read_mark_at :] if b"G1 X" in w]
    assert after == [], f"job lines written after the error: {after}"


def test_a_stop_the_port_did_not_take_is_answered_as_an_error(
    monkeypatch, make_printer, make_job
):
    """The write failed (the port went away): the client hears the stop did not go
    out, never "ok"."""
    from printers.models import QueuedCommand
    from printers.transport import TransportClosed

    class Unplugged(ScriptedMarlin):
        def write(self, data: bytes) -> None:
            if b"M112" in data:
                raise TransportClosed("/dev/ttyScripted: write failed: gone")
            super().write(data)

    firmware = Unplugged({})
    opens(monkeypatch, firmware)
    printer = make_printer(port="/dev/ttyScripted")
    worker = start_worker(printer)
    try:
        wait_for(lambda: worker.transport is not None, 5, "connected", step=worker.tick)
        stop = emergency_stop(printer, origin="tester")
        wait_for(
            lambda: QueuedCommand.objects.get(pk=stop.pk).reply, 5, "the reply",
            step=worker.tick,
        )  # fmt: skip
    finally:
        worker.stop()
    reply = QueuedCommand.objects.get(pk=stop.pk).reply
    assert reply.startswith("error: M112 was not written"), reply


def test_an_emergency_behind_hundreds_of_requests_goes_out_in_the_same_poll(
    monkeypatch, make_printer
):
    """The poll reads 200 rows at most: emergencies are read first, not in turn."""
    from printers.models import QueuedCommand

    firmware = ScriptedMarlin({})
    opens(monkeypatch, firmware)
    printer = make_printer(port="/dev/ttyScripted")
    worker = start_worker(printer)
    try:
        wait_for(lambda: worker.transport is not None, 5, "connected", step=worker.tick)
        QueuedCommand.objects.bulk_create(
            QueuedCommand(printer=printer, text=f"M117 note {n}", origin="tester")
            for n in range(250)
        )
        stop = emergency_stop(printer, origin="tester")
        worker.requests.poll(worker.clock())
        assert b"M112" in firmware.written
        assert QueuedCommand.objects.get(pk=stop.pk).state == "done"
    finally:
        worker.stop()


def test_an_emergency_command_goes_out_alone_whatever_follows_it(
    sim_factory, make_printer
):
    """`M108 \\rM500` or `M410\\x0bM502` is an emergency (its first word): the word
    goes out ahead of everything, the rest never reaches the firmware, and the
    worker goes on (it used to stop on the rest, and every worker after it, the
    row still pending)."""
    from jobs.commands import send_command
    from printers.models import QueuedCommand

    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "0")
    printer = make_printer(port=str(sim.link), baud=250000)
    worker = start_worker(printer)
    try:
        wait_for(lambda: worker.status.state == "idle", 10, "idle", worker.tick)
        rows = [send_command(printer, text) for text in ("M108 \rM500", "M410\x0bM502")]
        row = QueuedCommand.objects.create(
            printer=printer, kind="emergency", text="G28"
        )
        done = lambda: not QueuedCommand.objects.filter(state="pending").exists()
        wait_for(done, 10, "the rows answered", worker.tick)
        wait_for(lambda: "M410" in sim.executed(), 5, "M410 in the record")
    finally:
        worker.stop()
    replies = [QueuedCommand.objects.get(pk=r.pk).reply for r in (*rows, row)]
    assert replies == [
        "ok: M108 sent alone", "ok: M410 sent alone",
        "error: 'G28' is not an emergency command",
    ]  # fmt: skip
    assert not {"M500", "M502", "G28"} & set(sim.executed())


def test_a_request_the_worker_fails_on_is_answered_before_it_stops(
    sim_factory, make_printer, monkeypatch
):
    """A bug met while acting on a request stops the worker (and says why), but
    the request is answered first, so the next worker does not meet it again."""
    from printers.models import QueuedCommand

    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "0")
    printer = make_printer(port=str(sim.link), baud=250000)
    worker = start_worker(printer)
    try:
        wait_for(lambda: worker.status.state == "idle", 10, "idle", worker.tick)
        monkeypatch.setattr(
            worker.protocol, "send_emergency", lambda *a: 1 / 0, raising=False
        )
        row = emergency_stop(printer, origin="tester")
        with pytest.raises(ZeroDivisionError):
            wait_for(lambda: False, 10, "the worker to fail", worker.tick)
    finally:
        monkeypatch.undo()
        worker.stop()
    answered = QueuedCommand.objects.get(pk=row.pk)
    assert (answered.state, answered.reply) == (
        "failed", "error: the worker failed on this: ZeroDivisionError('division by zero')"
    )  # fmt: skip
