"""The worker against the GRBL simulator over real ptys: EEPROM writes, grblHAL,
alarms, check mode and jogging."""

from __future__ import annotations

import pytest

from jobs.commands import send_command
from jobs.models import Job
from printers.models import Printer, QueuedCommand
from printers.protocol.grbl_codes import JOG_CANCEL, jog_line
from printers.sample_gcode import commands_of, segments
from printers.worker.loop import PrinterWorker
from tests.conftest import job_lines, wait_for

pytestmark = pytest.mark.django_db


def start_worker(printer: Printer) -> PrinterWorker:
    worker = PrinterWorker(printer)
    worker.start()
    return worker


def job_state(job: Job) -> Job:
    return Job.objects.get(pk=job.pk)


def reply(row: QueuedCommand) -> str:
    return QueuedCommand.objects.get(pk=row.pk).reply


def saved(worker: PrinterWorker) -> Printer:
    worker.status.save_if_due(worker.clock(), force=True)
    return Printer.objects.get(pk=worker.printer.pk)


def stats(sim: object) -> dict[str, object]:
    return sim.stats()  # type: ignore[attr-defined]


def slow_moves(count: int) -> str:
    """*count* 1 mm moves at 600 mm/min: a tenth of a second each."""
    return "G21\nG90\n" + "".join(f"G1 X{i + 1} F600\n" for i in range(count))


def grbl_printer(make_printer, sim, **fields) -> Printer:
    return make_printer(port=str(sim.link), baud=115200, firmware="grbl", **fields)


def test_a_setting_sent_mid_job_is_refused_and_the_job_runs_unchanged(
    sim_factory, make_printer, make_job
):
    """It used to wait for GRBL to be idle (the job held, the tool in the work)
    and then change the machine under the rest of the job."""
    sim = sim_factory("grbl", "--baud", "115200", "--time-scale", "1")
    printer = grbl_printer(make_printer, sim)  # no regular status polls
    text = slow_moves(30)
    job = make_job(printer, text)
    worker = start_worker(printer)
    try:
        wait_for(lambda: len(job_lines(sim)) > 5, 20, "motion", step=worker.tick)
        setting = send_command(printer, "$110=600", origin="tester")
        wait_for(lambda: reply(setting), 20, "the setting's reply", step=worker.tick)
        wait_for(lambda: job_state(job).state != "printing", 20, "the job's end",
                 step=worker.tick)  # fmt: skip
        worker.log.flush()
        after = send_command(printer, "$110=600", origin="tester")
        wait_for(lambda: reply(after), 20, "the setting's reply", step=worker.tick)
    finally:
        worker.stop()

    assert reply(setting).startswith("error: '$110=600' would change what GRBL")
    job = job_state(job)
    assert job.state == Job.State.COMPLETED, job.message
    wait_for(lambda: len(job_lines(sim)) >= 32, 10, "the record")
    ran = [line for line in job_lines(sim) if not line.startswith("$")]
    assert ran == [c.replace(" ", "") for c in commands_of(text)]
    assert reply(after) == "ok", "GRBL refused the write once the job had ended"
    assert sim.executed().count("$110=600") == 1


def test_grblhal_gets_more_than_127_bytes_in_flight_and_never_overflows(
    sim_factory, make_printer, make_job
):
    sim = sim_factory("grbl", "--variant", "grblhal", "--time-scale", "1")
    printer = grbl_printer(make_printer, sim, status_interval=0.2)
    text = segments(400, cnc=True)
    job = make_job(printer, text)
    worker = start_worker(printer)
    most = 0

    def step() -> None:
        nonlocal most
        worker.tick()
        most = max(most, worker.protocol.bytes_in_flight)

    try:
        wait_for(lambda: job_state(job).state not in ("queued", "printing"), 60,
                 "the job's end", step=step)  # fmt: skip
        printer = saved(worker)
    finally:
        worker.stop()

    assert job_state(job).state == Job.State.COMPLETED
    assert most > 127, f"at most {most} bytes in flight"
    assert most <= 1023
    assert stats(sim)["dropped_bytes"] == 0
    wait_for(lambda: len(job_lines(sim)) >= 404, 10, "the record")
    executed = [c.replace(" ", "") for c in job_lines(sim)]
    assert executed == [c.replace(" ", "") for c in commands_of(text)]
    assert printer.firmware_name == "grblHAL 1.1f.20231210"
    caps = printer.capabilities
    assert (caps["rx_buffer"], caps["planner_blocks"]) == (1024, 15)
    assert caps["firmware"] == "grblHAL"
    assert caps["ver"] == "1.1f.20231210"
    assert caps["options"] == "VNMSL"


def test_grbl_1_1_build_facts_are_in_the_capabilities(sim_factory, make_printer):
    sim = sim_factory("grbl", "--time-scale", "0")
    printer = grbl_printer(make_printer, sim)
    worker = start_worker(printer)
    try:
        wait_for(lambda: worker.status.fields.get("capabilities", {}).get("rx_buffer"),
                 10, "the $I answer", step=worker.tick)  # fmt: skip
        printer = saved(worker)
    finally:
        worker.stop()

    assert printer.firmware_name == "Grbl 1.1h.20190825"
    assert printer.capabilities == {
        "ver": "1.1h.20190825",
        "info": "",
        "options": "V",
        "planner_blocks": 15,
        "rx_buffer": 128,
    }
    assert worker.protocol.rx_buffer == 127


def test_an_alarm_mid_job_stops_it_and_shows_until_unlocked(
    sim_factory, make_printer, make_job
):
    sim = sim_factory("grbl", "--time-scale", "1")
    printer = grbl_printer(make_printer, sim, status_interval=0.2)
    job = make_job(printer, slow_moves(100))
    worker = start_worker(printer)
    try:
        wait_for(lambda: len(job_lines(sim)) > 5, 20, "motion", step=worker.tick)
        assert sim.control("halt") == "ok"
        wait_for(lambda: job_state(job).state == "failed", 10, "the job to stop",
                 step=worker.tick)  # fmt: skip
        assert job_state(job).message.startswith("GRBL alarm: ALARM:1 hard limit")
        ran = len(job_lines(sim))
        for _ in range(30):  # the worker carries on, the job does not
            worker.tick()
        alarmed = saved(worker)
        # A hard limit wants a reset, then `$X`.
        reset = QueuedCommand.objects.create(printer=printer, text="\x18")
        wait_for(lambda: reply(reset) == "ok", 10, "the reset", step=worker.tick)
        wait_for(lambda: worker.grbl_alarm, 10, "the alarm after the reset",
                 step=worker.tick)  # fmt: skip
        after_reset = saved(worker)
        unlock = send_command(printer, "$X", origin="tester")
        wait_for(lambda: reply(unlock), 10, "the unlock", step=worker.tick)
        unlocked = saved(worker)
    finally:
        worker.stop()

    job = job_state(job)
    assert job.message.startswith("GRBL alarm: ALARM:1 hard limit hit")
    assert len(job_lines(sim)) == ran < 100
    assert alarmed.state == Printer.State.ERROR
    assert alarmed.state_message.startswith("ALARM:1 hard limit hit")
    assert "$X" in alarmed.state_message
    assert after_reset.state == Printer.State.ERROR
    assert after_reset.state_message.startswith("ALARM:1 hard limit hit")
    assert reply(unlock) == "ok"
    # The failed job leaves the bed to check (waitstart); the alarm is gone.
    assert unlocked.state == Printer.State.WAITSTART
    assert not worker.grbl_alarm


def test_a_job_in_check_mode_is_reported_as_a_dry_run(
    sim_factory, make_printer, make_job
):
    sim = sim_factory("grbl", "--time-scale", "1")
    printer = grbl_printer(make_printer, sim, status_interval=0.2)
    worker = start_worker(printer)
    try:
        check = send_command(printer, "$C", origin="tester")
        wait_for(lambda: reply(check), 10, "check mode", step=worker.tick)
        wait_for(lambda: saved(worker).machine_status.get("state") == "Check", 10,
                 "a Check report", step=worker.tick)  # fmt: skip
        checking = saved(worker)
        job = make_job(printer, slow_moves(20))
        wait_for(lambda: job_state(job).state not in ("queued", "printing"), 20,
                 "the dry run", step=worker.tick)  # fmt: skip
        after = saved(worker)
        leave = send_command(printer, "$C", origin="tester")  # GRBL resets after it
        wait_for(lambda: reply(leave), 10, "check mode off", step=worker.tick)
        wait_for(lambda: not saved(worker).machine_status["check_mode"], 10,
                 "check mode off in the status", step=worker.tick)  # fmt: skip
    finally:
        worker.stop()

    assert reply(check) == "ok"
    assert checking.machine_status["check_mode"] is True
    job = job_state(job)
    assert job.state == Job.State.COMPLETED
    assert "dry run" in job.message and "check mode" in job.message
    assert after.machine_status["MPos"] == "0.000,0.000,0.000"  # nothing moved


def test_jog_runs_and_jog_cancel_stops_it_out_of_band(sim_factory, make_printer):
    sim = sim_factory("grbl", "--time-scale", "1")
    printer = grbl_printer(make_printer, sim, status_interval=0.1)
    worker = start_worker(printer)
    try:
        jog = send_command(printer, jog_line({"x": 50}, 600), origin="tester")
        wait_for(lambda: worker.status.fields.get("machine_status", {}).get("state")
                 == "Jog", 10, "the jog", step=worker.tick)  # fmt: skip
        sent_before = worker.protocol.lines_sent
        cancel = send_command(printer, JOG_CANCEL, origin="tester")
        wait_for(lambda: worker.status.fields["machine_status"]["state"] == "Idle",
                 10, "the cancel", step=worker.tick)  # fmt: skip
        status = worker.status.fields["machine_status"]
    finally:
        worker.stop()

    assert reply(jog) == "ok"
    assert reply(cancel) == "ok"
    assert worker.protocol.lines_sent == sent_before  # 0x85 is no line
    assert 0 < float(status["MPos"].split(",")[0]) < 50
    assert "$J=G91 X50.000 F600" in sim.executed()


@pytest.mark.parametrize(
    ("moves", "feed", "error"),
    [
        ({}, 100, "at least one axis"),
        ({"E": 1}, 100, "axis E"),
        ({"X": 1}, 0, "positive"),
    ],
)
def test_bad_jogs_are_refused_with_a_reason(moves, feed, error):
    with pytest.raises(ValueError, match=error):
        jog_line(moves, feed)


def test_export_for_grbl_keeps_eeprom_writes(make_printer, make_job, tmp_path):
    from django.core.management import call_command

    printer = make_printer(firmware="grbl")
    job = make_job(printer, "G0 X1\nG10 L20 P1 X0\n$100=250\nG0 X2\n")
    out = tmp_path / "out.nc"

    call_command("export_job", str(job.pk), str(out))

    assert out.read_text().splitlines() == ["G0X1", "G10L20P1X0", "$100=250", "G0X2"]


def test_homing_clears_the_alarm_a_reset_during_motion_left(sim_factory, make_printer):
    sim = sim_factory("grbl", "--time-scale", "1")
    printer = grbl_printer(make_printer, sim)  # no status polls: messages only
    worker = start_worker(printer)
    try:
        move = send_command(printer, "G1 X50 F600", origin="tester")
        wait_for(lambda: reply(move), 10, "the move", step=worker.tick)
        reset = QueuedCommand.objects.create(printer=printer, text="\x18")
        wait_for(lambda: worker.grbl_alarm, 10, "the alarm", step=worker.tick)
        alarmed = saved(worker)
        home = send_command(printer, "$H", origin="tester")
        wait_for(lambda: reply(home), 20, "homing", step=worker.tick)
        homed = saved(worker)
    finally:
        worker.stop()

    assert reply(reset) == "ok"
    assert alarmed.state == Printer.State.ERROR
    assert alarmed.state_message.startswith("ALARM:3 reset during motion")
    assert reply(home) == "ok"
    assert homed.state == Printer.State.IDLE


def test_a_job_with_eeprom_writes_between_moves_runs_every_line_once(
    sim_factory, make_printer, make_job
):
    sim = sim_factory("grbl", "--time-scale", "1")
    printer = grbl_printer(make_printer, sim)
    text = (
        slow_moves(10)
        + "$110=600\nG10 L20 P1 X0\n"
        + "".join(f"G1 X{i} F600\n" for i in range(10, 0, -1))
        + "G28.1\nM2\n"
    )
    job = make_job(printer, text)
    worker = start_worker(printer)
    try:
        wait_for(lambda: job_state(job).state not in ("queued", "printing"), 30,
                 "the job's end", step=worker.tick)  # fmt: skip
    finally:
        worker.stop()

    job = job_state(job)
    assert job.state == Job.State.COMPLETED, job.message
    expected = [c.replace(" ", "") for c in commands_of(text)]
    wait_for(lambda: len(sim.executed()) >= len(expected) + 1, 10, "the record")
    ran = [c.replace(" ", "") for c in sim.executed() if c != "$I"]
    assert ran == expected
    assert stats(sim)["dropped_bytes"] == 0
