"""One worker per port on a computer: an exclusive lock the kernel lets go of.

`run_printer` takes the lock before it claims the printer's lease and holds it
for its life; a second worker for the same port (another runhost, a hand-started
`run_printer`, a restart while the old process lingers) is refused before it
writes anything. The kernel drops a `flock` when its process dies, SIGKILL
included, so a dead worker never leaves the port locked. The lock is what lets a
worker keep driving its printer while the database is away: nobody else on this
computer can open the port, and no other host may claim the printer (the lease
names the printer's own worker host).

Two names of one device (`/dev/serial/by-id/...` and `/dev/ttyUSB0`) share one
lock: the name is resolved first.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
from pathlib import Path

from django.conf import settings


class PortBusy(Exception):
    """Another process on this computer holds the port; the message says which."""


def lock_dir() -> Path:
    return Path(settings.DATA_DIR) / "locks"


def _key(port: str) -> str:
    if "://" not in port:
        port = os.path.realpath(port)
    return hashlib.sha256(port.encode()).hexdigest()[:20]


class PortLock:
    """The exclusive lock on one port for this process (`acquire`, `release`)."""

    def __init__(self, port: str, directory: Path | None = None) -> None:
        self.port = port
        self.path = (directory or lock_dir()) / f"port-{_key(port)}.lock"
        self._fd: int | None = None

    def acquire(self) -> None:
        """Take the lock now or raise PortBusy (never waits)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 64).decode("ascii", "replace").strip() or "?"
            os.close(fd)
            raise PortBusy(
                f"{self.port} is driven by another worker on this computer (pid "
                f"{holder}); one port, one worker"
            ) from None
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing drops the flock
            self._fd = None

    @property
    def held(self) -> bool:
        return self._fd is not None
