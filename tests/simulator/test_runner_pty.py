"""The simulator process on a real pty (and TCP): pacing, overflow, record, control, signals."""

from __future__ import annotations

import json
import os
import select
import socket
import time
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
import serial

from printers.protocol.checksum import format_line
from printers.simulator.cli import main
from printers.simulator.process import SimulatorProcess, start_simulator

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

ROOT = Path(__file__).resolve().parents[2]
BOOT = [
    "start",
    "echo:Marlin 2.1.2.4",
    "",
    "echo: Last Updated: 2024-06-20 | Author: (printhost simulator)",
    "echo:Compiled: Jun 20 2024",
    "echo: Free Memory: 2683  PlannerBufferBytes: 1600",
]


Running = SimulatorProcess


def _start(directory: Path, firmware: str, *args: str) -> Running:
    return start_simulator(directory, firmware, *args, name="printer")


@pytest.fixture
def start_sim(tmp_path: Path) -> Iterator[Callable[..., Running]]:
    started: list[Running] = []

    def start(firmware: str = "marlin", *args: str) -> Running:
        sim = _start(tmp_path, firmware, *args)
        started.append(sim)
        return sim

    yield start
    for sim in started:
        sim.stop()


class Host:
    """The host end of a port: bounded waits for lines, never a sleep."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.buffer = b""
        self.lines: list[str] = []

    @classmethod
    def open(cls, path: Path) -> tuple[Host, serial.SerialBase]:
        port = serial.serial_for_url(str(path), baudrate=115200, timeout=0)
        return cls(port.fileno()), port

    def write(self, data: str | bytes) -> None:
        os.write(self.fd, data.encode() if isinstance(data, str) else data)

    def read_until(
        self, done: Callable[[list[str]], bool], timeout: float = 5.0
    ) -> list[str]:
        deadline = time.monotonic() + timeout
        while not done(self.lines):
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"timed out; got {self.lines!r}")
            if select.select([self.fd], [], [], left)[0]:
                self.buffer += os.read(self.fd, 65536)
                *complete, self.buffer = self.buffer.split(b"\n")
                self.lines += [line.decode().rstrip("\r") for line in complete]
        return self.lines

    def until_line(self, prefix: str, timeout: float = 5.0) -> list[str]:
        return self.read_until(
            lambda lines: any(x.startswith(prefix) for x in lines), timeout
        )

    def until_oks(self, count: int, timeout: float = 5.0) -> list[str]:
        return self.read_until(lambda lines: _oks(lines) >= count, timeout)


def _oks(lines: list[str]) -> int:
    return sum(line.startswith("ok") for line in lines)


def wait_until(predicate: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)  # polling a file or a process, bounded by the deadline


def test_ready_line_and_boot_banner(start_sim):
    sim = start_sim("marlin", "--tcp", "127.0.0.1:0")
    assert sim.info["ready"] is True
    assert sim.info["pty"] == str(sim.link)
    assert str(sim.info["tcp"]).startswith("127.0.0.1:")
    assert sim.info["pid"] == sim.process.pid
    # A plain open does not flush the input, so the banner written at boot is there.
    fd = os.open(sim.link, os.O_RDWR | os.O_NOCTTY)
    try:
        lines = Host(fd).until_line("echo: Free Memory")
    finally:
        os.close(fd)
    assert lines == BOOT


def test_checksummed_line_gets_ok_and_corrupted_line_a_resend(start_sim):
    sim = start_sim("marlin")
    host, _port = Host.open(sim.link)
    host.write(format_line(1, "G1 X10 F3000") + "\n")
    assert host.until_oks(1) == ["ok N1 P14 B3"]  # the move is in the planner
    host.write("N2 G1 X20*1\n")
    assert host.until_oks(2)[1:] == [
        "Error:checksum mismatch, Last Line: 1",
        "Resend: 2",
        "ok",
    ]


def test_baud_rate_is_enforced(start_sim):
    sim = start_sim("marlin", "--baud", "9600")
    host, _port = Host.open(sim.link)
    lines = [f"M117 {n:04} " + "x" * 29 + "\n" for n in range(50)]  # 40 bytes each
    started = time.monotonic()
    host.write("".join(lines))
    host.until_oks(50, timeout=20)
    assert time.monotonic() - started >= 0.95 * 2000 * 10 / 9600


def test_latency_delays_both_directions(start_sim):
    sim = start_sim("marlin", "--latency-ms", "150")
    host, _port = Host.open(sim.link)
    started = time.monotonic()
    host.write("M105\n")
    host.until_oks(1)
    assert time.monotonic() - started >= 0.29


def test_overflow_drops_bytes_when_the_host_ignores_the_window(start_sim):
    sim = start_sim("marlin")
    host, _port = Host.open(sim.link)
    blob = "G4 P1000\n" + "M117 q\n" * 3  # the dwell blocks; the queue fills
    blob += "".join(
        f"M117 {n:04}\n" for n in range(30)
    )  # 300 bytes for a 128-byte ring
    host.write(blob)
    host.until_oks(1 + 3 + 12)  # 12 whole lines fitted the ring
    host.write("\nM105\n")  # ends the cut 13th line, then asks for temperatures
    lines = host.until_line("ok T:")
    assert _oks(lines) == 1 + 3 + 12 + 2
    assert json.loads(sim.control("stats")[3:])["dropped_bytes"] == 300 - 128


def test_record_lists_executed_commands(start_sim):
    sim = start_sim("marlin")
    host, _port = Host.open(sim.link)
    host.write(format_line(1, "G1 X1 Y2") + "\n" + "N2 G1 X2*0\n")
    host.until_oks(2)
    host.write(format_line(2, "G1 X3") + "\nM105\n")
    host.until_oks(4)
    expected = ["G1 X1 Y2", "G1 X3", "M105"]
    wait_until(lambda: sim.record.read_text().splitlines() == expected, 5, "the record")


def test_executed_asks_the_simulator_to_write_its_record_out_first(start_sim):
    sim = start_sim("marlin")
    host, _port = Host.open(sim.link)
    host.write("M105\n")
    host.until_oks(1)
    host.write("M114\n")  # executed within 50 ms of M105: the record holds it back
    host.until_oks(1)
    assert sim.executed() == ["M105", "M114"]


def test_tcp_client_talks_to_the_same_firmware_and_a_new_client_replaces_it(start_sim):
    sim = start_sim("grbl", "--tcp", "127.0.0.1:0")
    host, port = str(sim.info["tcp"]).rsplit(":", 1)
    first = socket.create_connection((host, int(port)), timeout=5)
    first.sendall(b"$I\n")
    first_host = Host(first.fileno())
    assert first_host.until_oks(1) == ["[VER:1.1h.20190825:]", "[OPT:V,15,128]", "ok"]
    second = socket.create_connection((host, int(port)), timeout=5)
    assert first.recv(100) == b""  # the old client was dropped
    second.sendall(b"?")
    assert Host(second.fileno()).until_line("<Idle|")[0].startswith("<Idle|MPos:")
    first.close()
    second.close()


def test_control_reset_reboots_the_firmware(start_sim):
    sim = start_sim("marlin")
    host, _port = Host.open(sim.link)
    assert sim.control("reset") == "ok"
    assert host.until_line("echo: Free Memory") == BOOT
    assert sim.control("bogus").startswith("error: unknown command")
    assert sim.control("busy soon").startswith("error: busy")


def test_control_close_and_reopen_the_port(start_sim):
    sim = start_sim("marlin")
    assert sim.control("close") == "ok"
    assert not sim.link.exists()
    assert sim.control("reopen") == "ok"
    host, _port = Host.open(sim.link)
    host.write("M105\n")
    assert host.until_oks(1)[0].startswith("ok T:")


def test_close_after_n_commands_then_reopen(start_sim):
    sim = start_sim("marlin", "--close-after", "2", "--reopen-after", "0.3")
    host, _port = Host.open(sim.link)
    host.write("M105\n")
    host.until_oks(1)
    host.write("M105\n")  # the second command: the port closes after it
    wait_until(lambda: not sim.link.exists(), 5, "the port to close")
    wait_until(sim.link.exists, 5, "the port to come back")
    host, _port = Host.open(sim.link)
    host.write(format_line(1, "M105") + "\n")  # line numbers start over
    assert host.until_oks(1)[0].startswith("ok T:")


def test_grbl_answers_status_and_lines_over_the_pty(start_sim):
    sim = start_sim("grbl", "--time-scale", "0")
    host, _port = Host.open(sim.link)
    host.write("?G0 X5\n$G\n")
    lines = host.until_oks(2)
    assert (
        lines[0]
        == "<Idle|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,0|WCO:0.000,0.000,0.000>"
    )
    assert lines[1:] == ["ok", "[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]", "ok"]
    wait_until(
        lambda: sim.record.read_text().splitlines() == ["G0 X5", "$G"], 5, "record"
    )


def test_sigterm_removes_the_link_and_the_control_socket(start_sim):
    sim = start_sim("marlin")
    assert sim.link.is_symlink()
    assert sim.stop() == 0
    assert not sim.link.exists()
    assert not sim.link.is_symlink()
    assert not sim.control_path.exists()
    assert sim.record.exists()


def test_a_stale_link_is_replaced(start_sim, tmp_path):
    (tmp_path / "printer.tty").symlink_to("/dev/pts/nonexistent")
    sim = start_sim("marlin")
    assert os.readlink(sim.link).startswith("/dev/pts/")
    assert sim.link.exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["marlin"], "--link"),
        (["klipper", "--link", "x"], "invalid choice"),
        (["marlin", "--link", "/nonexistent/dir/tty"], "does not exist"),
        (["marlin", "--tcp", "localhost"], "HOST:PORT"),
        (["marlin", "--link", "x", "--corrupt", "2"], "corrupt"),
    ],
)
def test_bad_arguments_exit_with_status_2(argv, message, capsys):
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_link_path_that_is_a_regular_file_is_refused(tmp_path, capsys):
    path = tmp_path / "file"
    path.write_text("not a link")
    assert main(["marlin", "--link", str(path)]) == 2
    assert "not a symlink" in capsys.readouterr().err
    assert path.read_text() == "not a link"
