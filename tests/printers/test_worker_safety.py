"""Safety: emergency stop ahead of everything, resets and lost ports stop the job."""

from __future__ import annotations

import time

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


def wait_until_failed(worker: PrinterWorker, job: Job) -> None:
    wait_for(
        lambda: job_state(job).state == "failed", 10, "the job to fail",
        step=worker.tick,
    )  # fmt: skip


def logged(printer: Printer, **kind: int) -> list[str]:
    """The printer's response log in order (*kind*: of that kind only)."""
    lines = ResponseLine.objects.filter(printer=printer, **kind).order_by("seq")
    return list(lines.values_list("text", flat=True))


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


def test_an_emergency_stop_is_ended_by_an_operator_not_by_the_board_coming_back(
    sim_factory, make_printer, make_job
):
    """A board reset (its button, a power blip) or a port that came back by itself
    is no one saying the machine is safe again: with auto_start, the next job
    started on it. Only the operator's reconnect ends the stop."""
    from jobs.commands import request_action

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
