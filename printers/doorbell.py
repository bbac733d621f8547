"""A worker's doorbell on SQLite: what PostgreSQL's NOTIFY is to a worker
(printers/worker/wakeup.py), made of a named pipe in the data directory.

A worker in a process of its own (`run_printer`, as `runhost` starts them) makes
`<data dir>/doorbells/printer-<id>`, a FIFO of mode 0600 in a directory of mode
0700, and waits on it beside its serial port. Whoever commits a request or a
queued job for the printer writes one byte to it (`ring_at_commit`: the signal
in printers/apps.py, and the bulk updates that queue jobs), as
the PostgreSQL triggers notify. The worker then reads its requests at once
instead of at its next poll, and polls only every
`PRINTHOST_FALLBACK_POLL_SECONDS`, as it does while it LISTENs.

A ring is a hint, never a message: it says "look", and the worker reads the
database as after a notification. A ring that is lost (no worker listening, the
pipe full, a write that does not ring) costs the fallback poll, never a request.
Only the user printhost runs as can open the pipe (its mode and its
directory's), and `ring` writes only to a FIFO (a file or a link put in its
place is left alone).
"""

from __future__ import annotations

import errno
import logging
import os
import stat
from functools import partial
from pathlib import Path
from typing import Any

from django.conf import settings
from django.db import connections, transaction

__all__ = ["Doorbell", "bell_path", "ring", "ring_at_commit", "ring_for_saved"]

logger = logging.getLogger("printhost.worker")

#: Bytes a drain reads at most in one call (a ring is one byte; many are one look).
DRAIN_BYTES = 4096


def bell_path(printer_id: int) -> Path:
    """The doorbell of one printer's worker."""
    return Path(settings.DATA_DIR) / "doorbells" / f"printer-{int(printer_id)}"


def ring(printer_id: int) -> bool:
    """Write one byte to the printer's doorbell; False when nobody listens (no
    pipe, no worker reading it, or something else in its place). Never blocks."""
    flags = os.O_WRONLY | os.O_NONBLOCK | os.O_NOFOLLOW | os.O_CLOEXEC
    try:
        fd = os.open(bell_path(printer_id), flags)
    except OSError:  # ENOENT, ENXIO (no reader), ELOOP (a link): nobody to wake
        return False
    try:
        if not stat.S_ISFIFO(os.fstat(fd).st_mode):
            return False
        os.write(fd, b"\x01")
    except OSError as error:
        # A full pipe has been rung already: the worker will look.
        return error.errno in (errno.EAGAIN, errno.EWOULDBLOCK)
    finally:
        os.close(fd)
    return True


def ring_at_commit(printer_id: int | None, *, using: str = "default") -> None:
    """Ring the printer's doorbell once the current transaction commits (at once
    outside one). Only on SQLite: on PostgreSQL the triggers notify."""
    if printer_id is None or connections[using].vendor != "sqlite":
        return
    transaction.on_commit(partial(ring, printer_id), using=using)


def ring_for_saved(
    sender: type, instance: Any, *, created: bool = False, **kwargs: Any
) -> None:
    """`post_save` of a request or a job (connected in printers/apps.py): a new
    request, or a job saved queued, rings its printer at commit; as the
    PostgreSQL triggers (jobs/migrations/0010) notify on insert and on queued."""
    wakes = instance.state == "queued" if sender._meta.label == "jobs.Job" else created
    if wakes:
        ring_at_commit(instance.printer_id, using=kwargs.get("using") or "default")


class Doorbell:
    """The worker's end: the pipe, made on the first `fileno()` and removed by
    `close()`."""

    def __init__(self, printer_id: int) -> None:
        self.path = bell_path(printer_id)
        self._read: int | None = None
        #: The worker's own write end: without a writer open, a pipe whose last
        #: ringer closed would read as ended, readable at every wait.
        self._write: int | None = None
        self._failed = False

    def fileno(self) -> int | None:
        """The descriptor to wait on; None if the pipe cannot be made (the worker
        then polls, as without a doorbell)."""
        if self._read is None and not self._failed:
            try:
                self._open()
            except OSError as error:
                self._failed = True
                self.close()
                logger.warning(
                    "%s: no doorbell (%s); requests are read at the poll instead",
                    self.path.name, error,
                )  # fmt: skip
        return self._read

    def _open(self) -> None:
        folder = self.path.parent
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)
        folder.chmod(0o700)
        # A pipe left by a worker that was killed: ours is a new one.
        self.path.unlink(missing_ok=True)
        os.mkfifo(self.path, 0o600)
        self._read = os.open(self.path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
        self._write = os.open(self.path, os.O_WRONLY | os.O_NONBLOCK | os.O_CLOEXEC)

    def drain(self) -> bool:
        """Take every ring waiting; whether there was one."""
        if self._read is None:
            return False
        rung = False
        while True:
            try:
                data = os.read(self._read, DRAIN_BYTES)
            except BlockingIOError:
                return rung
            if not data:
                return rung
            rung = True

    def close(self) -> None:
        """Close the pipe and remove it, if it is still this worker's."""
        read, write = self._read, self._write
        self._read = self._write = None
        try:
            if read is not None and self.path.stat().st_ino == os.fstat(read).st_ino:
                self.path.unlink()
        except OSError:
            pass
        for fd in (read, write):
            if fd is not None:
                os.close(fd)
