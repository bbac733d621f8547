"""Printing from the printer's own SD card, and copying jobs onto it, over real ptys."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import pytest

from jobs.commands import request_action, send_command
from jobs.models import Job
from jobs.sdcard import delete_sd_file, queue_sd_print, queue_sd_upload
from jobs.services import enqueue_job
from printers.models import Printer, QueuedCommand
from printers.sample_gcode import commands_of, segments
from printers.worker.loop import PrinterWorker
from tests.conftest import job_lines, wait_for
from tests.printers.stream_checks import USER_DEFAULTS, sim_stats

if TYPE_CHECKING:
    from pathlib import Path

    from tests.conftest import Sim

pytestmark = pytest.mark.django_db

#: What the worker sends about the card itself (not lines of the job's file).
CARD_COMMANDS = ("M20", "M21", "M23", "M24", "M25", "M27", "M28", "M30", "M524")


def stored(printer: Printer, tmp_path: Path, text: str, name: str) -> Job:
    source = tmp_path / name
    source.write_text(text)
    return enqueue_job(printer, source, name=name, queue=False)


def card_folder(tmp_path: Path, **files: str) -> Path:
    """A folder the simulator uses as its SD card, holding *files* (name=text)."""
    folder = tmp_path / "card"
    folder.mkdir()
    for name, text in files.items():
        (folder / name.replace("_", ".")).write_text(text)
    return folder


def card(sim: Sim) -> dict[str, object]:
    return json.loads(sim.control("sd").removeprefix("ok "))


def printed(sim: Sim) -> list[str]:
    """The job commands the firmware ran (from the card or the link)."""
    wait_for(lambda: len(sim.executed()) >= sim_stats(sim)["executed"], 5, "the record")
    return [c for c in job_lines(sim) if not c.startswith(CARD_COMMANDS)]


def state_of(job: Job) -> str:
    return Job.objects.get(pk=job.pk).state


def running(printer: Printer) -> PrinterWorker:
    worker = PrinterWorker(printer)
    worker.start()
    return worker


def listed(printer: Printer) -> dict[str, int]:
    printer.refresh_from_db()
    return {f["name"]: f["size"] for f in (printer.sd_card or {}).get("files", [])}


def test_copy_to_the_card_then_print_from_it_runs_every_line_once(
    sim_factory, make_printer, tmp_path
):
    # A user's defaults: temperature polling on. No M105 may land in the file.
    sd_dir = card_folder(tmp_path)
    sim = sim_factory("marlin", "--time-scale", "0", "--sd-dir", str(sd_dir))
    printer = make_printer(port=str(sim.link), auto_start=True, **USER_DEFAULTS)
    text = segments(300)
    source = stored(printer, tmp_path, text, "bracket holder.gcode")
    upload = queue_sd_upload(printer, source, print_after=True)
    worker = running(printer)
    try:
        wait_for(lambda: state_of(upload) == "completed", 60, "the copy",
                 step=worker.tick)  # fmt: skip
        sd_print = Job.objects.get(kind=Job.Kind.SD_PRINT)
        wait_for(lambda: state_of(sd_print) == "completed", 60, "the print",
                 step=worker.tick)  # fmt: skip
        wait_for(lambda: "BRACKE~1.GCO" in listed(printer), 10, "the listing",
                 step=worker.tick)  # fmt: skip
    finally:
        worker.stop()
    assert upload.sd_name == "BRACKE~1.GCO"
    written = (sd_dir / "BRACKE~1.GCO").read_text().splitlines()
    assert written == commands_of(text), "the file on the card is not the job's"
    assert printed(sim) == commands_of(text)
    assert sim_stats(sim)["dropped_bytes"] == 0
    sd_print.refresh_from_db()
    assert sd_print.sd_name == "BRACKE~1.GCO"
    assert sd_print.progress == 1.0


def test_copy_to_the_card_survives_line_noise_with_every_line_exact(
    sim_factory, make_printer, tmp_path
):
    sd_dir = card_folder(tmp_path)
    sim = sim_factory(
        "marlin", "--time-scale", "0", "--sd-dir", str(sd_dir),
        "--corrupt", "0.03", "--seed", "7",
    )  # fmt: skip
    printer = make_printer(port=str(sim.link), **USER_DEFAULTS)
    text = segments(400)
    upload = queue_sd_upload(
        printer, stored(printer, tmp_path, text, "noisy.gcode"), sd_name="noisy.gco"
    )
    worker = running(printer)
    try:
        wait_for(lambda: card(sim)["writing"], 30, "M28 to open the file",
                 step=worker.tick)  # fmt: skip
        # A user's command during the copy waits for it: it would land in the file.
        command = send_command(printer, "M117 hello", origin="tester")
        wait_for(lambda: state_of(upload) != "queued" and state_of(upload) !=
                 "printing", 90, "the copy", step=worker.tick)  # fmt: skip
        wait_for(lambda: QueuedCommand.objects.get(pk=command.pk).reply, 10,
                 "the command's reply", step=worker.tick)  # fmt: skip
        worker.tick()
        shown = worker.status.state
    finally:
        worker.stop()
    upload.refresh_from_db()
    assert upload.state == "completed", upload.message
    assert worker.protocol.resends > 0  # the noise did hit the copy
    written = (sd_dir / "NOISY.GCO").read_text().splitlines()
    assert written == commands_of(text)
    assert printed(sim) == ["M117 hello"]  # after the copy; nothing of the file ran
    assert QueuedCommand.objects.get(pk=command.pk).reply == "ok"
    assert shown == "idle"  # a copy printed nothing: no bed to clear


def test_print_from_the_card_shows_progress_and_pauses_resumes_and_aborts(
    sim_factory, make_printer, tmp_path
):
    sd_dir = card_folder(tmp_path, LONG_GCO=segments(400))
    sim = sim_factory("marlin", "--time-scale", "1", "--sd-dir", str(sd_dir))
    printer = make_printer(port=str(sim.link), **USER_DEFAULTS)
    job = queue_sd_print(printer, "long.gco")
    worker = running(printer)

    def progress() -> int:
        return Job.objects.get(pk=job.pk).bytes_acked

    try:
        wait_for(lambda: progress() > 0, 30, "progress from the card",
                 step=worker.tick)  # fmt: skip
        request_action(printer, "pause")
        wait_for(lambda: state_of(job) == "paused" and not card(sim)["printing"],
                 10, "the printer to pause", step=worker.tick)  # fmt: skip
        request_action(printer, "resume")
        wait_for(lambda: state_of(job) == "printing" and card(sim)["printing"],
                 10, "the printer to resume", step=worker.tick)  # fmt: skip
        request_action(printer, "abort")
        wait_for(lambda: state_of(job) == "aborted", 10, "the abort",
                 step=worker.tick)  # fmt: skip
        wait_for(lambda: not card(sim)["printing"], 10, "the printer to stop",
                 step=worker.tick)  # fmt: skip
    finally:
        worker.stop()
    job.refresh_from_db()
    assert job.size_bytes == (sd_dir / "LONG.GCO").stat().st_size
    assert 0 < job.bytes_acked < job.size_bytes
    ran = printed(sim)
    assert 0 < len(ran) < 400
    assert ran == commands_of(segments(400))[: len(ran)]  # in order, none twice


def test_a_file_the_printer_cannot_open_fails_the_job_with_its_words(
    sim_factory, make_printer, tmp_path
):
    sim = sim_factory("marlin", "--time-scale", "0", "--sd-dir", str(tmp_path))
    printer = make_printer(port=str(sim.link))
    job = queue_sd_print(printer, "MISSING.GCO")
    worker = running(printer)
    try:
        wait_for(lambda: state_of(job) == "failed", 20, "the job to fail",
                 step=worker.tick)  # fmt: skip
    finally:
        worker.stop()
    job.refresh_from_db()
    assert job.message == "the printer could not open MISSING.GCO on its SD card"


def test_the_card_is_listed_at_connect_and_a_deleted_file_leaves_the_list(
    sim_factory, make_printer, tmp_path
):
    sd_dir = card_folder(tmp_path, CUBE_GCO="G1 X1\n", BOAT_GCO="G1 X2\nG1 X3\n")
    sim = sim_factory("marlin", "--time-scale", "0", "--sd-dir", str(sd_dir))
    printer = make_printer(port=str(sim.link))
    worker = running(printer)
    try:
        wait_for(lambda: set(listed(printer)) == {"CUBE.GCO", "BOAT.GCO"}, 20,
                 "the listing at connect", step=worker.tick)  # fmt: skip
        row = delete_sd_file(printer, "cube.gco", origin="tester")
        wait_for(lambda: set(listed(printer)) == {"BOAT.GCO"}, 20,
                 "the listing after M30", step=worker.tick)  # fmt: skip
    finally:
        worker.stop()
    row.refresh_from_db()
    assert row.reply == "ok"
    assert not (sd_dir / "CUBE.GCO").exists()
    assert listed(printer) == {"BOAT.GCO": len("G1 X2\nG1 X3\n")}


def test_a_copy_to_a_printer_without_a_card_runs_none_of_the_files_lines(
    sim_factory, make_printer, tmp_path
):
    # M28 unknown: had the lines gone on, the printer would have printed them.
    sim = sim_factory("marlin", "--time-scale", "0")
    printer = make_printer(port=str(sim.link), **USER_DEFAULTS)
    text = segments(50)
    upload = queue_sd_upload(printer, stored(printer, tmp_path, text, "a.gcode"))
    worker = running(printer)
    try:
        wait_for(lambda: state_of(upload) == "failed", 20, "the copy to fail",
                 step=worker.tick)  # fmt: skip
    finally:
        worker.stop()
    upload.refresh_from_db()
    assert upload.message.startswith("the printer did not open A.GCO on its SD card")
    assert printed(sim) == []
    assert "M29" not in sim.executed()


def test_a_print_stopped_on_the_printers_display_ends_the_job(
    sim_factory, make_printer, tmp_path
):
    sd_dir = card_folder(tmp_path, LONG_GCO=segments(400))
    sim = sim_factory("marlin", "--time-scale", "1", "--sd-dir", str(sd_dir))
    printer = make_printer(port=str(sim.link), **USER_DEFAULTS)
    job = queue_sd_print(printer, "LONG.GCO")
    worker = running(printer)
    try:
        wait_for(lambda: card(sim)["printing"], 30, "the print", step=worker.tick)
        sim.control("sd-stop")
        wait_for(lambda: state_of(job) == "aborted", 20, "the job to end",
                 step=worker.tick)  # fmt: skip
    finally:
        worker.stop()
    job.refresh_from_db()
    assert job.message == (
        "the printer stopped printing LONG.GCO by itself (cancelled on its display?)"
    )


def test_not_sd_printing_after_a_pause_was_asked_is_not_a_stop(make_printer):
    # The display's pause sends //action:pause, then M25 makes the printer report
    # `Not SD printing`: read in one chunk, the pause must win, not an abort.
    from printers.protocol.marlin import MarlinProtocol
    from printers.streaming import StreamHost
    from tests.streaming.test_host import Wire

    worker = PrinterWorker(make_printer())
    worker.host = StreamHost(MarlinProtocol(checksums="never", flow="ping_pong"))
    job = Job(pk=1, name="LONG.GCO", sd_name="LONG.GCO", kind=Job.Kind.SD_PRINT)
    stream = worker.sd.print_stream(job)
    worker.host.submit(stream)
    Wire(worker.host).run(5)  # M23, M24 acknowledged: the printer prints

    worker.host.request_pause(script=True)
    worker.sd.receive("Not SD printing")
    assert worker.host.requested == "pause"

    worker.host.advance(0.0)
    worker.sd.receive("Not SD printing")  # paused now: still no stop
    assert worker.host.requested == ""
    assert stream.outcome == ""


def test_a_card_name_with_brackets_is_refused_not_cut_to_another_file():
    """`M30 KEEP(1).GCO` would go out as `M30 KEEP.GCO`: brackets are a comment to
    the host's line cleaning and to Marlin built with PAREN_COMMENTS."""
    from jobs.sdcard import BadCardName, card_name

    with pytest.raises(BadCardName, match="no brackets"):
        card_name("KEEP(1).GCO")
    assert card_name("/sub/keep_1.gco") == "/SUB/KEEP_1.GCO"


def test_the_file_being_printed_cannot_be_deleted_under_another_spelling(
    sim_factory, make_printer, tmp_path
):
    sd_dir = card_folder(tmp_path, CUBE_GCO=segments(400))
    sim = sim_factory("marlin", "--time-scale", "1", "--sd-dir", str(sd_dir))
    printer = make_printer(port=str(sim.link), **USER_DEFAULTS)
    job = queue_sd_print(printer, "cube.gco")
    worker = running(printer)
    try:
        wait_for(lambda: Job.objects.get(pk=job.pk).bytes_acked > 0, 30,
                 "the print from the card", step=worker.tick)  # fmt: skip
        refusals = [worker.sd.delete(name) for name in ("/cube.gco", " Cube.GCO")]
    finally:
        worker.stop()
    assert refusals == [
        f"{name} is in use by job {job.pk}; abort the job first"
        for name in ("/cube.gco", " Cube.GCO")
    ]
    assert (sd_dir / "CUBE.GCO").exists()


def test_a_copy_leaves_out_what_marlin_would_take_for_m29_and_esp_commands(
    sim_factory, make_printer, tmp_path
):
    """Marlin ends a file being written at "M29" anywhere in a line (is_M29), and
    runs the lines after it: M502 and M500 would reset and save the settings."""
    sd_dir = card_folder(tmp_path)
    sim = sim_factory("marlin", "--time-scale", "0", "--sd-dir", str(sd_dir))
    printer = make_printer(port=str(sim.link), **USER_DEFAULTS)
    text = (
        "G1 X1\nM117 Copy M29 ok\nM502\nM500\n[ESP700]macro.gcode\nM290 Z0.1\n"
        "M28 OTHER.GCO\nG1 X2\n"
    )
    upload = queue_sd_upload(printer, stored(printer, tmp_path, text, "copy.gcode"))
    worker = running(printer)
    try:
        wait_for(lambda: state_of(upload) == "completed", 30, "the copy",
                 step=worker.tick)  # fmt: skip
    finally:
        worker.stop()
    written = (sd_dir / "COPY.GCO").read_text().splitlines()
    assert written == ["G1 X1", "M502", "M500", "M290 Z0.1", "G1 X2"]
    assert not {"M502", "M500"} & set(sim.executed()), "a line ran during the copy"
