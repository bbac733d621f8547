"""The job journal: the last acknowledged line, written on every ack batch.

The database gets a job's progress once a second; a worker killed in between would
leave it up to a second stale, and a restart from there would repeat extrusion. So
each printer has a small file in the data dir: two slots of one line each,
`<job id> <lines acked> <lines sent> <bytes acked> <seq> <check>` padded to SLOT
bytes. An entry goes into the slot that does not hold the newest one, through a
shared memory map of the file: a store into the kernel's page cache, no system
call (the loop writes one nearly every turn, and a system call a turn was a
tenth of what the loop spent on a line).

No fsync: a killed process (SIGKILL, a crash) loses nothing it already stored in
the mapped pages, which are the kernel's; only a power cut or a kernel crash could,
and then the printer lost power or its host too, so the line it stopped at is
unknown anyway. A process killed in the middle of a store leaves that slot torn:
its check (CRC-32 of the rest of the line) fails and the other slot, one entry
older, is the journal's last entry. An entry that repeats the last one is not
written.
"""

from __future__ import annotations

import mmap
import os
import zlib
from dataclasses import dataclass
from pathlib import Path

from django.conf import settings

#: Bytes of one slot, its newline included (fields of 20 digits fit).
SLOT = 128


@dataclass(frozen=True)
class Entry:
    """How far one job got, as the worker last saw it acknowledged."""

    job_id: int
    acked: int
    sent: int
    bytes_acked: int


def journal_dir() -> Path:
    """Where journals live: PRINTHOST_JOURNAL_DIR, or `journal/` in the data dir."""
    configured = getattr(settings, "PRINTHOST_JOURNAL_DIR", None)
    return Path(configured) if configured else Path(settings.DATA_DIR) / "journal"


class Journal:
    """One printer's journal; only its worker (the lease holder) writes it."""

    def __init__(self, printer_id: int, directory: Path | None = None) -> None:
        self.path = (directory or journal_dir()) / f"printer-{printer_id}.log"
        self._fd: int | None = None
        self._map: mmap.mmap | None = None
        self._seq = 0
        self._last_fields: tuple[int, int, int, int] | None = None

    def last(self) -> Entry | None:
        """The newest whole entry in the file (a torn slot is ignored)."""
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            return None
        return newest(data)

    def record(self, entry: Entry) -> None:
        """Store *entry* unless it repeats the last one."""
        self.progress(entry.job_id, entry.acked, entry.sent, entry.bytes_acked)

    def progress(self, job_id: int, acked: int, sent: int, bytes_acked: int) -> None:
        """`record` without building an Entry (the loop calls it every turn)."""
        fields = (job_id, acked, sent, bytes_acked)
        if fields == self._last_fields:
            return
        if self._map is None:
            self._reopen()
        self._store(fields)
        self._last_fields = fields

    def _store(self, fields: tuple[int, int, int, int]) -> None:
        assert self._map is not None
        self._seq += 1
        job_id, acked, sent, bytes_acked = fields
        body = f"{job_id} {acked} {sent} {bytes_acked} {self._seq}"
        check = zlib.crc32(body.encode("ascii"))
        line = f"{body} {check}".encode("ascii").ljust(SLOT - 1) + b"\n"
        at = (self._seq % 2) * SLOT
        self._map[at : at + SLOT] = line

    def _reopen(self) -> None:
        """Start the file afresh (a new job): keep only the last entry, if any."""
        last = self._last_fields
        self.close()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o644)
        os.ftruncate(self._fd, 2 * SLOT)
        self._map = mmap.mmap(self._fd, 2 * SLOT, mmap.MAP_SHARED)
        self._map[:] = (b" " * (SLOT - 1) + b"\n") * 2
        self._seq = 0
        if last is not None:
            self._store(last)

    def start_job(self) -> None:
        """A new job starts: what the previous one journaled is no longer needed."""
        self._last_fields = None
        self._reopen()

    def close(self) -> None:
        if self._map is not None:
            self._map.close()
            self._map = None
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def newest(data: bytes) -> Entry | None:
    """The newest whole entry of a journal file's bytes (a torn slot is left out).

    A file of an earlier printhost (one `<job> <acked> <sent> <bytes>` line per
    entry, appended) gives its last whole line.
    """
    best: tuple[int, Entry] | None = None
    for order, raw in enumerate(data.split(b"\n")):
        found = _parse(raw, order)
        if found is not None and (best is None or found[0] > best[0]):
            best = found
    return None if best is None else best[1]


def _parse(raw: bytes, order: int) -> tuple[int, Entry] | None:
    """One slot (or an earlier line) as (its rank, the entry); None when torn."""
    parts = raw.split()
    if not parts or not all(p.isdigit() for p in parts):
        return None
    if len(parts) == 4:  # the earlier format: later lines are newer
        return -(1 << 62) + order, Entry(*map(int, parts))
    if len(parts) != 6:
        return None
    body = b" ".join(parts[:5])
    if zlib.crc32(body) != int(parts[5]):
        return None
    job_id, acked, sent, bytes_acked, seq = map(int, parts[:5])
    return seq, Entry(job_id, acked, sent, bytes_acked)
