"""Shared fixtures: firmware simulators on real ptys, printers, and bounded waits."""

from __future__ import annotations

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
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

ROOT = Path(__file__).resolve().parent.parent


@dataclass
class Sim:
    """A firmware simulator process on a pty, with its record file and control socket."""

    process: subprocess.Popen[bytes]
    link: Path
    record: Path
    control_path: Path
    tcp: str | None = None
    argv: list[str] = field(default_factory=list)

    def control(self, command: str, timeout: float = 5.0) -> str:
        """Send one control command (reset, close, reopen, busy 5 ...) and read the answer."""
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
        if not self.record.exists():
            return []
        return self.record.read_text().splitlines()

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


def start_sim(directory: Path, firmware: str, *args: str, name: str = "") -> Sim:
    """Start `python -m printers.simulator` and wait (bounded) for its ready line."""
    name = name or firmware
    link = directory / f"{name}.tty"
    record = directory / f"{name}.record"
    control = directory / f"{name}.control"
    argv = [
        sys.executable, "-m", "printers.simulator", firmware,
        "--link", str(link), "--record", str(record), "--control", str(control), *args,
    ]  # fmt: skip
    process = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE)
    ready = _read_line(process, timeout=20)
    info = json.loads(ready)
    return Sim(process, link, record, control, info.get("tcp"), argv)


def _read_line(process: subprocess.Popen[bytes], timeout: float) -> str:
    assert process.stdout is not None
    deadline = time.monotonic() + timeout
    buffer = b""
    while b"\n" not in buffer:
        left = deadline - time.monotonic()
        if left <= 0 or process.poll() is not None:
            raise AssertionError(f"simulator did not get ready: {buffer!r}")
        ready, _, _ = select.select([process.stdout], [], [], left)
        if ready:
            buffer += os.read(process.stdout.fileno(), 4096)
    return buffer.split(b"\n", 1)[0].decode()


@pytest.fixture
def sim_factory(tmp_path: Path) -> Iterator[Callable[..., Sim]]:
    """Start simulators in this test's folder; all are stopped afterwards."""
    started: list[Sim] = []

    def factory(firmware: str, *args: str, name: str = "") -> Sim:
        sim = start_sim(tmp_path, firmware, *args, name=name)
        started.append(sim)
        return sim

    yield factory
    for sim in started:
        sim.stop()


def wait_for(
    predicate: Callable[[], object],
    timeout: float,
    what: str,
    step: Callable[[], None] | None = None,
) -> None:
    """Call *step* (or poll) until *predicate* holds; fail with *what* after *timeout*."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        if step is not None:
            step()
        else:
            time.sleep(0.02)


@pytest.fixture
def storage(settings: object, tmp_path: Path) -> Path:
    """Job files inside this test's folder, and a fast worker poll."""
    settings.JOB_STORAGE_DIR = tmp_path / "jobs"  # type: ignore[attr-defined]
    settings.PRINTHOST_POLL_SECONDS = 0.02  # type: ignore[attr-defined]
    return tmp_path / "jobs"


@pytest.fixture
def make_printer(db: None, storage: Path) -> Callable[..., object]:
    """Create a printer row; keyword arguments override the defaults."""
    from printers.models import Printer

    def factory(**fields: object) -> Printer:
        values: dict[str, object] = {
            "name": "Test printer",
            "slug": f"p{Printer.objects.count() + 1}",
            "port": "/nonexistent",
            "temperature_interval": 0,
            "status_interval": 0,
            "ack_timeout": 5.0,
        }
        values.update(fields)
        return Printer.objects.create(**values)

    return factory


@pytest.fixture
def make_job(storage: Path, tmp_path: Path) -> Callable[..., object]:
    """Queue a job holding *text* on *printer* through the real enqueue path."""
    from jobs.services import enqueue_job

    def factory(printer: object, text: str, name: str = "job.gcode") -> object:
        source = tmp_path / name
        source.write_text(text)
        return enqueue_job(printer, source, name=name, origin="test")

    return factory
