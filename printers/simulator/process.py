"""A simulator as a child process: start it, wait for its ready line, steer it, stop it.

Used by the tests and the benchmarks; `runhost` starts simulators its own way.
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent.parent


@dataclass
class SimulatorProcess:
    """A running `python -m printers.simulator`, with its record file and control socket."""

    process: subprocess.Popen[bytes]
    link: Path
    record: Path
    control_path: Path
    info: dict[str, object] = field(default_factory=dict)

    @property
    def tcp(self) -> str | None:
        return self.info.get("tcp")  # type: ignore[return-value]

    def control(self, command: str, timeout: float = 5.0) -> str:
        """Send one control command (reset, close, reopen, busy 5...); return the answer."""
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            sock.settimeout(timeout)
            sock.connect(str(self.control_path))
            sock.sendall(command.encode() + b"\n")
            reply = b""
            while not reply.endswith(b"\n"):
                chunk = sock.recv(4096)
                if not chunk:
                    break
                reply += chunk
        return reply.decode().strip()

    def executed(self) -> list[str]:
        """Commands the firmware executed so far, in order."""
        return [line.split("\t@", 1)[0] for line in self.recorded()]

    def stats(self) -> dict[str, object]:
        """The simulator's counters and state (`stats` on the control socket):
        executed commands, faults, state."""
        answer = self.control("stats")
        if not answer.startswith("ok "):
            raise RuntimeError(f"stats: {answer}")
        return json.loads(answer[3:])

    def recorded(self) -> list[str]:
        """The record's lines (`--record-state` adds each command's state). A running
        simulator writes its record every 50 ms; it is asked to write it out first."""
        if self.process.poll() is None:
            with contextlib.suppress(OSError):
                self.control("flush")
        if not self.record.exists():
            return []
        return self.record.read_text().splitlines()

    def stop(self) -> int:
        """SIGTERM, then SIGKILL after 10 s; returns the exit code."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        return self.process.returncode


def start_simulator(
    directory: Path, firmware: str, *args: str, name: str = "", ready_within: float = 20
) -> SimulatorProcess:
    """Start a simulator with its link, record and control socket in *directory*."""
    name = name or firmware
    link = directory / f"{name}.tty"
    record = directory / f"{name}.record"
    control = directory / f"{name}.control"
    argv = [
        sys.executable, "-m", "printers.simulator", firmware, "--link", str(link),
        "--record", str(record), "--control", str(control), *args,
    ]  # fmt: skip
    process = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE)
    info = json.loads(_ready_line(process, ready_within))
    return SimulatorProcess(process, link, record, control, info)


def _ready_line(process: subprocess.Popen[bytes], timeout: float) -> str:
    assert process.stdout is not None
    deadline = time.monotonic() + timeout
    buffer = b""
    while b"\n" not in buffer:
        left = deadline - time.monotonic()
        if left <= 0 or process.poll() is not None:
            process.kill()
            raise RuntimeError(f"the simulator did not get ready: {buffer!r}")
        if select.select([process.stdout], [], [], left)[0]:
            buffer += os.read(process.stdout.fileno(), 4096)
    return buffer.split(b"\n", 1)[0].decode()
