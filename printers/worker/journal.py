"""The job journal: the last acknowledged line, appended on every ack batch.

The database gets a job's progress once a second; a worker killed in between would
leave it up to a second stale, and a restart from there would repeat extrusion. So
each printer has a small append-only file in the data dir: one line per ack batch,
`<job id> <lines acked> <lines sent> <bytes acked>`, written and flushed to the OS.

No fsync: a killed process (SIGKILL, a crash) loses nothing it already handed to the
kernel; only a power cut or a kernel crash could, and then the printer lost power
or its host too, so the line it stopped at is unknown anyway. An fsync per batch
would cost the loop milliseconds (on SD cards, tens) for that case. Each entry is
one `os.write` on the file descriptor (no Python buffer to flush), and an ack
batch that moved nothing writes nothing.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from django.conf import settings

#: The file is rewritten from scratch once it holds this many bytes.
COMPACT_BYTES = 1 << 20


@dataclass(frozen=True)
class Entry:
    """How far one job got, as the worker last saw it acknowledged."""

    job_id: int
    acked: int
    sent: int
    bytes_acked: int

    def line(self) -> str:
        return f"{self.job_id} {self.acked} {self.sent} {self.bytes_acked}\n"


def journal_dir() -> Path:
    """Where journals live: PRINTHOST_JOURNAL_DIR, or `journal/` in the data dir."""
    configured = getattr(settings, "PRINTHOST_JOURNAL_DIR", None)
    return Path(configured) if configured else Path(settings.DATA_DIR) / "journal"


class Journal:
    """One printer's journal; only its worker (the lease holder) writes it."""

    def __init__(self, printer_id: int, directory: Path | None = None) -> None:
        self.path = (directory or journal_dir()) / f"printer-{printer_id}.log"
        self._fd: int | None = None
        self._size = 0
        self._last: Entry | None = None
        self._last_fields: tuple[int, int, int, int] | None = None

    def last(self) -> Entry | None:
        """The last complete entry in the file (a torn final line is ignored)."""
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            return None
        for raw in reversed(data.split(b"\n")[:-1]):
            entry = _parse(raw)
            if entry is not None:
                return entry
        return None

    def record(self, entry: Entry) -> None:
        """Append *entry* unless it repeats the last one; handed to the OS at once."""
        self.progress(entry.job_id, entry.acked, entry.sent, entry.bytes_acked)

    def progress(self, job_id: int, acked: int, sent: int, bytes_acked: int) -> None:
        """`record` without building an Entry (the loop calls it every turn)."""
        fields = (job_id, acked, sent, bytes_acked)
        if fields == self._last_fields:
            return
        if self._fd is None or self._size >= COMPACT_BYTES:
            self._reopen()
        entry = Entry(*fields)
        self._write(entry.line())
        self._last, self._last_fields = entry, fields

    def _write(self, line: str) -> None:
        assert self._fd is not None
        data = line.encode("ascii")
        written = os.write(self._fd, data)
        if written < len(
            data
        ):  # a regular file takes it whole, unless the disk is full
            os.write(self._fd, data[written:])
        self._size += len(data)

    def _reopen(self) -> None:
        """Start the file afresh (a new job, or compaction): keep only the last entry."""
        self.close()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self._size = 0
        if self._last is not None:
            self._write(self._last.line())

    def start_job(self) -> None:
        """A new job starts: what the previous one journaled is no longer needed."""
        self._last = self._last_fields = None
        self._reopen()

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def _parse(raw: bytes) -> Entry | None:
    parts = raw.split()
    if len(parts) != 4 or not all(p.isdigit() for p in parts):
        return None
    job_id, acked, sent, bytes_acked = (int(p) for p in parts)
    return Entry(job_id, acked, sent, bytes_acked)
