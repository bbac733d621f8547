"""The simulated Marlin's SD card inside the firmware: M28 writing, printing from it."""

from __future__ import annotations

from printers.protocol.checksum import format_line
from tests.simulator.test_marlin_firmware import Bench


def numbered(bench: Bench, start: int, *commands: str) -> list[str]:
    out: list[str] = []
    for n, command in enumerate(commands, start=start):
        out += bench.framed(n, command)
    return out


def oks(lines: list[str]) -> int:
    return sum(line.startswith("ok") for line in lines)


def test_without_sdsupport_the_card_commands_are_unknown():
    bench = Bench()
    assert bench.send("M20\n")[0] == 'echo:Unknown command: "M20"'
    assert "Cap:SDCARD:0" in bench.send("M115\n")


def test_m115_reports_the_card_when_there_is_one():
    out = Bench(sd_card=True).send("M115\n")
    assert {"Cap:SDCARD:1", "Cap:AUTOREPORT_SD_STATUS:1"} <= set(out)


def test_lines_after_m28_are_written_acked_and_never_run():
    bench = Bench(sd_card=True)
    out = numbered(bench, 1, "M28 PART.GCO", "G28", "G1 X10", "M104 S200", "M29")
    assert "Writing to file: PART.GCO" in out
    assert "Done saving file." in out
    assert oks(out) == 5
    assert bench.executed == ["M28 PART.GCO"]
    assert bench.fw.sd.files["PART.GCO"] == b"G28\nG1 X10\nM104 S200\n"


def test_a_line_refused_during_the_upload_is_written_once_after_its_resend():
    bench = Bench(sd_card=True)
    numbered(bench, 1, "M28 PART.GCO", "G1 X1")
    bad = format_line(3, "G1 X2").replace("*", "*1")  # a wrong checksum
    out = bench.send(bad + "\n")
    assert "Resend: 3" in out
    numbered(bench, 3, "G1 X2", "G1 X3", "M29")
    assert bench.fw.sd.files["PART.GCO"] == b"G1 X1\nG1 X2\nG1 X3\n"


def test_printing_from_the_card_runs_every_line_in_order_without_oks():
    bench = Bench(sd_card=True)
    bench.fw.sd.files["CUBE.GCO"] = b"G28\n; a comment\nG1 X1\nG1 X2\nM400\n"
    out = bench.send("M23 CUBE.GCO\nM24\n")
    out += bench.advance(1.0)
    assert bench.executed == ["M23 CUBE.GCO", "M24", "G28", "G1 X1", "G1 X2", "M400"]
    assert oks(out) == 2  # M23 and M24; the card's lines came from no port
    assert "Done printing file" in out


def test_pause_resume_and_abort_of_a_print_from_the_card():
    bench = Bench(sd_card=True, time_scale=1.0)
    moves = "".join(f"G1 X{10 * (i % 2)} F600\n" for i in range(100))
    bench.fw.sd.files["LONG.GCO"] = moves.encode()
    bench.send("M23 LONG.GCO\nM24\n")
    bench.advance(2.0)
    bench.send("M25\n")
    bench.advance(30.0)  # what was queued finishes; nothing new is read
    ran = len(bench.executed)
    bench.advance(5.0)
    assert len(bench.executed) == ran
    assert bench.send("M27\n")[0] == "Not SD printing"
    bench.send("M24\n")
    bench.advance(3.0)
    assert len(bench.executed) > ran + 1
    bench.send("M524\n")
    bench.advance(30.0)
    stopped = len(bench.executed)
    bench.advance(5.0)
    assert len(bench.executed) == stopped < 100 + 4


def test_m27_s_reports_progress_by_itself():
    bench = Bench(sd_card=True, time_scale=1.0)
    bench.fw.sd.files["LONG.GCO"] = b"G1 X10 F600\nG1 X0 F600\n" * 10
    bench.send("M23 LONG.GCO\nM24\nM27 S1\n")
    out = bench.advance(3.5)
    reports = [line for line in out if "SD printing" in line]
    assert len(reports) == 3  # at 1, 2 and 3 s
    assert reports[0].startswith("SD printing byte ")
    assert reports[0].endswith("/230")
    assert reports[-1] == "Not SD printing"  # the whole file was read by then


def test_the_card_keeps_its_files_through_a_reset(tmp_path):
    bench = Bench(sd_dir=tmp_path)
    numbered(bench, 1, "M28 KEEP.GCO", "G1 X1", "M29")
    bench.fw.reset(bench.now)
    bench.send("")  # the boot banner
    assert (tmp_path / "KEEP.GCO").read_bytes() == b"G1 X1\n"
    out = bench.send("M20\n")
    assert out[:3] == ["Begin file list", "KEEP.GCO 6", "End file list"]


def test_a_folder_card_lists_only_8_3_names_and_deletes_for_real(tmp_path):
    (tmp_path / "CUBE.GCO").write_text("G1 X1\n")
    (tmp_path / "long name.gcode").write_text("G1 X1\n")
    bench = Bench(sd_dir=tmp_path)
    assert bench.send("M20\n")[:3] == ["Begin file list", "CUBE.GCO 6", "End file list"]
    assert "File deleted:CUBE.GCO" in bench.send("M30 cube.gco\n")
    assert not (tmp_path / "CUBE.GCO").exists()
