"""[ESP700] and [ESP701] from any client, through the worker, answered to their origin."""

from __future__ import annotations

import json

import pytest

from jobs.commands import send_command
from jobs.models import Job
from jobs.services import storage_dir
from printers.models import QueuedCommand, ResponseLine
from printers.sample_gcode import commands_of, segments
from printers.streaming.esp import EspError, EspFileRequest, EspStreamControl, parse_esp
from printers.streaming.streams import StreamType
from printers.worker.loop import PrinterWorker
from tests.conftest import wait_for


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (
            "[ESP700]stream=/sd/a.gco",
            EspFileRequest(StreamType.SD_FILE_STREAM, "a.gco", False),
        ),
        (
            "[ESP700]stream=/fs/a.gco",
            EspFileRequest(StreamType.FS_FILE_STREAM, "a.gco", False),
        ),
        (
            "[ESP700]/sd/m.gco",
            EspFileRequest(StreamType.SD_FILE_SCRIPT, "m.gco", False),
        ),
        (
            "[ESP700]/fs/m.gco json=yes",
            EspFileRequest(StreamType.FS_FILE_SCRIPT, "m.gco", True),
        ),
        ("[ESP701]action=PAUSE", EspStreamControl("PAUSE", False)),
        ("[ESP701]action=abort json=yes", EspStreamControl("ABORT", True)),
        ("[ESP701]", EspStreamControl("", False)),
    ],
)
def test_parse_esp_reads_the_seed_forms(text, expected):
    assert parse_esp(text) == expected


@pytest.mark.parametrize(
    ("text", "error"),
    [
        ("[ESP700]stream=/usb/a.gco", "must start with /sd/ or /fs/"),
        ("[ESP700]stream=/sd/../x", "not a file name"),
        ("[ESP700]", "needs a file"),
        ("[ESP701]action=EXPLODE", "unknown action"),
        ("[ESP800]", "not supported"),
    ],
)
def test_parse_esp_refuses_bad_commands_with_a_reason(text, error):
    with pytest.raises(EspError, match=error):
        parse_esp(text)


pytestmark_db = pytest.mark.django_db


def reply_of(row: QueuedCommand, worker: PrinterWorker) -> str:
    wait_for(
        lambda: QueuedCommand.objects.get(pk=row.pk).state in ("done", "failed"),
        10, f"an answer to {row.text}", step=worker.tick,
    )  # fmt: skip
    return QueuedCommand.objects.get(pk=row.pk).reply


@pytest.fixture
def worker(sim_factory, make_printer):
    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "0")
    printer = make_printer(port=str(sim.link), baud=250000, auto_start=True)
    worker = PrinterWorker(printer)
    worker.start()
    worker.sim = sim
    yield worker
    worker.stop()


@pytestmark_db
def test_esp700_stream_queues_a_stored_file_as_a_job(worker):
    printer = worker.printer
    (storage_dir(printer) / "part.gcode").write_text(segments(30))

    reply = reply_of(send_command(printer, "[ESP700]stream=/sd/part.gcode"), worker)

    assert reply.startswith("queued as job ")
    job = Job.objects.get(pk=int(reply.rsplit(" ", 1)[1]))
    wait_for(lambda: Job.objects.get(pk=job.pk).state == "completed", 20, "the job",
             step=worker.tick)  # fmt: skip


@pytestmark_db
def test_esp700_script_runs_a_stored_file_through_the_script_queue(worker):
    printer = worker.printer
    (storage_dir(printer) / "macro.gcode").write_text("G28\nM117 macro done\n")

    assert reply_of(send_command(printer, "[ESP700]/fs/macro.gcode"), worker) == "ok"
    wait_for(lambda: "M117 macro done" in worker.sim.executed(), 10, "the macro",
             step=worker.tick)  # fmt: skip


@pytestmark_db
def test_esp700_on_a_worker_host_says_the_files_are_on_the_control_plane(
    worker, settings
):
    printer = worker.printer
    (storage_dir(printer) / "part.gcode").write_text(segments(30))
    settings.PRINTHOST_WORKER_HOST = "shelf-1"

    for text in ("[ESP700]stream=/sd/part.gcode", "[ESP700]/fs/part.gcode"):
        reply = reply_of(send_command(printer, text), worker)
        assert reply.startswith(
            "error: [ESP700] reads the printer's storage, which is on the control "
            "plane, not on worker host shelf-1"
        ), reply
    assert not Job.objects.filter(printer=printer).exists()


@pytestmark_db
def test_esp701_controls_and_reports_the_running_stream(worker, make_job):
    printer = worker.printer
    text = segments(3000)
    job = make_job(printer, text)
    # Paused once some lines are acknowledged, so that `processed` has counted them
    # (a loaded machine could pause before the first ok was read).
    wait_for(lambda: worker.host.printing and worker.host.current_stream.acked > 0,
             10, "the job's first acks", step=worker.tick)  # fmt: skip

    assert reply_of(send_command(printer, "[ESP701]action=PAUSE"), worker) == "ok"
    wait_for(lambda: Job.objects.get(pk=job.pk).state == "paused", 10, "pause",
             step=worker.tick)  # fmt: skip
    status = json.loads(reply_of(send_command(printer, "[ESP701]json=yes"), worker))
    assert status["cmd"] == "701"
    assert status["data"]["status"] == "paused"
    assert status["data"]["processed"] > 0
    assert reply_of(send_command(printer, "[ESP701]action=RESUME"), worker) == "ok"
    wait_for(lambda: Job.objects.get(pk=job.pk).state == "completed", 30, "the job",
             step=worker.tick)  # fmt: skip
    expected = [c for c in commands_of(text) if c.startswith("G1 X")]
    ran = lambda: [c for c in worker.sim.executed() if c.startswith("G1 X")]
    wait_for(lambda: len(ran()) >= len(expected), 5, "the record")
    assert ran() == expected


@pytestmark_db
def test_esp701_with_nothing_running_says_idle_and_pause_is_refused(worker):
    printer = worker.printer
    assert reply_of(send_command(printer, "[ESP701]"), worker) == "status: idle"
    reply = reply_of(send_command(printer, "[ESP701]action=PAUSE"), worker)
    assert reply == "error: no stream is running"


@pytestmark_db
def test_esp700_script_checks_the_file_like_an_upload_before_sending_a_line(worker):
    printer = worker.printer
    (storage_dir(printer) / "bin.gcode").write_bytes(b"M117 first\nG1 X1\x01\x02\n")
    long_line = "M117 " + "x" * 200
    (storage_dir(printer) / "long.gcode").write_text(f"M117 before\n{long_line}\n")

    binary = reply_of(send_command(printer, "[ESP700]/sd/bin.gcode"), worker)
    too_long = reply_of(send_command(printer, "[ESP700]/fs/long.gcode"), worker)
    stream = reply_of(send_command(printer, "[ESP700]stream=/sd/bin.gcode"), worker)

    assert binary.startswith("error: bin.gcode line 2: control byte 0x01")
    assert too_long.startswith("error: long.gcode line 2: command is 205 characters")
    assert stream.startswith("error: bin.gcode line 2")
    assert reply_of(send_command(printer, "M117 marker"), worker) == "ok"
    wait_for(lambda: "M117 marker" in worker.sim.executed(), 10, "the marker",
             step=worker.tick)  # fmt: skip
    executed = worker.sim.executed()
    assert "M117 first" not in executed
    assert "M117 before" not in executed
    assert not Job.objects.exists()


@pytestmark_db
def test_a_file_that_runs_itself_stops_at_the_nesting_limit(worker):
    """A macro may run a macro, a few deep: one that runs itself (twice) does not
    run for ever."""
    from printers.worker.esp_commands import MAX_DEPTH

    printer = worker.printer
    (storage_dir(printer) / "loop.gcode").write_text(
        "M117 pass\n[ESP700]/fs/loop.gcode\n[ESP700]/fs/loop.gcode\n"
    )
    assert reply_of(send_command(printer, "[ESP700]/fs/loop.gcode"), worker) == "ok"
    wait_for(
        lambda: not worker.host.script_queue, 30, "the macros to run out",
        step=worker.tick,
    )  # fmt: skip
    worker.log.flush()
    passes = worker.sim.executed().count("M117 pass")
    assert passes == 2 ** (MAX_DEPTH + 1) - 1  # each level runs it twice, then no more
    refused = ResponseLine.objects.filter(
        printer=printer, text__contains=f"at most {MAX_DEPTH} deep"
    )
    assert refused.exists()


@pytestmark_db
def test_a_file_cannot_queue_jobs(worker, make_job):
    """[ESP700]stream= read from a job would queue a job each time that job runs."""
    printer = worker.printer
    (storage_dir(printer) / "again.gcode").write_text("M117 once\n")
    job = make_job(printer, "M117 job\n[ESP700]stream=/sd/again.gcode\nM117 end\n")
    wait_for(
        lambda: Job.objects.get(pk=job.pk).state == "completed", 20, "the job",
        step=worker.tick,
    )  # fmt: skip
    worker.log.flush()
    assert Job.objects.count() == 1
    assert ResponseLine.objects.filter(
        printer=printer, text__contains="cannot be used inside a file"
    ).exists()
