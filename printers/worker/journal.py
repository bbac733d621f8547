"""The job journal: the last acknowledged line, appended on every ack batch.

The database gets a job's progress once a second; a worker killed in between would
leave it up to a second stale, and a restart from there would repeat extrusion. So
each printer has a small append-only file in the data dir: one line per ack batch,
`<job id> <lines acked> <lines sent> <bytes acked>`, written and flushed to the OS.

No fsync: a killed process (SIGKILL, a crash) loses nothing it already handed to the
kernel; only a power cut or a kernel crash could, and then the printer lost power
or its host too, so the line it stopped at is unknown anyway. An fsync per batch
would cost the loop milliseconds (on SD cards, tens) for that case.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import IO

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
        self._file: IO[str] | None = None
        self._last: Entry | None = None

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
        """Append *entry* unless it repeats the last one; flushed to the OS at once."""
        if entry == self._last:
            return
        if self._file is None or self._file.tell() >= COMPACT_BYTES:
            self._reopen()
        assert self._file is not None
        self._file.write(entry.line())
        self._file.flush()
        self._last = entry

    def _reopen(self) -> None:
        """Start the file afresh (a new job, or compaction): keep only the last entry."""
        self.close()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("w", encoding="ascii")
        if self._last is not None:
            self._file.write(self._last.line())

    def start_job(self) -> None:
        """A new job starts: what the previous one journaled is no longer needed."""
        self._last = None
        self._reopen()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def _parse(raw: bytes) -> Entry | None:
    parts = raw.split()
    if len(parts) != 4 or not all(p.isdigit() for p in parts):
        return None
    job_id, acked, sent, bytes_acked = (int(p) for p in parts)
    return Entry(job_id, acked, sent, bytes_acked)
