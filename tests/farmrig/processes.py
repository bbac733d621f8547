"""A runhost in its own session (process group), so a whole host can be SIGKILLed at
once; and what its workers cost, read from /proc."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

from tests.conftest import ROOT

#: Clock ticks a second, for /proc/<pid>/stat's utime and stime.
TICKS = os.sysconf("SC_CLK_TCK")


@dataclass
class Runhost:
    """`manage.py runhost <args>` with *env*, logging to *log* (appended)."""

    name: str
    args: list[str]
    env: dict[str, str]
    log: Path
    process: subprocess.Popen[bytes] | None = None
    starts: int = field(default=0)
    #: Stopped or killed on purpose (the harness does not take it for a crash).
    down: bool = False

    def start(self) -> None:
        with self.log.open("ab") as log:
            self.process = subprocess.Popen(
                [sys.executable, "manage.py", "runhost", *self.args], cwd=ROOT,
                env=self.env, stdout=log, stderr=subprocess.STDOUT,
                start_new_session=True,
            )  # fmt: skip
        self.starts += 1
        self.down = False

    @property
    def pid(self) -> int:
        assert self.process is not None
        return self.process.pid

    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def stop(self, grace: float = 60.0) -> None:
        """SIGTERM to runhost (it stops its children in order), then SIGKILL to the
        whole group after *grace* seconds."""
        if self.process is None:
            return
        self.down = True
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.process.wait(timeout=grace)
        self.kill()

    def kill(self) -> None:
        """SIGKILL runhost and every process of its group: the computer dies."""
        if self.process is None:
            return
        self.down = True
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.process.pid, signal.SIGKILL)
        self.process.wait()

    def log_text(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""

    def workers(self) -> dict[str, int]:
        """slug -> pid of each `run_printer <slug>` in this runhost's group."""
        if not self.alive():
            return {}
        found = {}
        for entry in Path("/proc").iterdir():
            if not entry.name.isdigit():
                continue
            try:
                argv = (entry / "cmdline").read_bytes().split(b"\0")
                group = os.getpgid(int(entry.name))
            except (OSError, ProcessLookupError):
                continue
            if group == self.pid and b"run_printer" in argv:
                found[argv[argv.index(b"run_printer") + 1].decode()] = int(entry.name)
        return found


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds *pid* used so far (None once it is gone)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat.rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS
