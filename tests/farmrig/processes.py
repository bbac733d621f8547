"""A runhost in its own session (process group), so a whole host can be SIGKILLed at
once; and what its workers cost, read from /proc."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
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
        self.terminate()
        self.finish(time.monotonic() + grace)

    def terminate(self) -> None:
        """SIGTERM to runhost: it begins to stop its children (see finish)."""
        if self.process is None:
            return
        self.down = True
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)

    def finish(self, until: float) -> None:
        """Wait for a terminated runhost until the monotonic time *until*, then
        SIGKILL what is left of its group."""
        if self.process is None:
            return
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.process.wait(timeout=max(0.0, until - time.monotonic()))
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


#: What a process of the farm is, by a word of its command line (first match wins).
KINDS = (
    ("run_printer", "workers"),
    ("printers.simulator", "simulators"),
    ("printhost.serve", "daphne"),
    ("celery", "celery"),
    ("run_dispatcher", "dispatcher"),
    ("fetch_files", "fetchers"),
    ("runhost", "runhost"),
    ("postgres", "postgresql"),
    ("redis-server", "redis"),
)


def cpu_by_kind() -> dict[str, float]:
    """CPU seconds used so far by every process of each kind (KINDS), and by this
    process (`harness`: the benchmark and its clients); per pid, so a kind's
    share over a span is the difference of two readings of the pids alive in both."""
    out: dict[str, float] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            command = (entry / "cmdline").read_bytes().replace(b"\0", b" ")
        except OSError:
            continue
        if int(entry.name) == os.getpid():
            kind = "harness"
        else:
            kind = next((k for word, k in KINDS if word.encode() in command), "")
        used = cpu_seconds(int(entry.name)) if kind else None
        if used is not None:
            out[f"{kind}:{entry.name}"] = used
    return out


def shares(before: dict[str, float], after: dict[str, float], wall: float) -> dict:
    """Cores used by each kind between two `cpu_by_kind` readings *wall* s apart."""
    cores: dict[str, float] = {}
    for key, used in after.items():
        if key in before:
            kind = key.split(":", 1)[0]
            cores[kind] = cores.get(kind, 0.0) + (used - before[key]) / wall
    return {k: round(v, 3) for k, v in sorted(cores.items(), key=lambda kv: -kv[1])}
