"""Repetier's response log, written in batches so logging never slows the stream.

The worker only writes it: the log is trimmed to the printer's `response_log_limit`
by the upkeep (`printers/upkeep.py`, from Celery beat), never in the worker's loop.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from django.db import connections, transaction
from django.db.models import Max
from django.utils import timezone

from printers import broadcast
from printers.models import ResponseLine

if TYPE_CHECKING:
    from contextlib import AbstractContextManager
    from datetime import datetime

    from printers.worker.lease import Lease

#: Flush at least this often (s) and whenever this many lines wait.
FLUSH_SECONDS = 0.25
FLUSH_LINES = 1000


class ResponseLog:
    """Numbers lines per printer (ids only grow) and stores them in batches.

    Only the printer's worker writes here (the lease makes it the only one), so the
    next id is simply one past the highest stored.
    """

    def __init__(self, printer_id: int, *, lease: Lease | None = None) -> None:
        self.printer_id = printer_id
        #: Lines are stored only while this lease is held (None: unconditional).
        self.lease = lease
        last = ResponseLine.objects.filter(printer_id=printer_id).aggregate(
            last=Max("seq")
        )["last"]
        self.last_id: int = last or 0
        self._buffer: list[tuple[int, datetime, str, int]] = []
        self._flush_at = 0.0

    def add(self, text: str, kind: int) -> int:
        """Log one line; returns its id."""
        self.last_id += 1
        self._buffer.append((self.last_id, timezone.now(), text, int(kind)))
        return self.last_id

    def due(self, now: float) -> float:
        """When the next flush must happen (monotonic seconds)."""
        return self._flush_at if self._buffer else now + FLUSH_SECONDS

    def flush_if_due(self, now: float) -> None:
        if len(self._buffer) >= FLUSH_LINES or (self._buffer and now >= self._flush_at):
            self.flush()
        if not self._buffer:
            self._flush_at = now + FLUSH_SECONDS

    def flush(self) -> None:
        """Write every buffered line in one transaction.

        Plain executemany instead of bulk_create: no model instances, so a batch of a
        few hundred lines costs a couple of milliseconds, not ten, of the loop's time.
        """
        if not self._buffer:
            return
        table = ResponseLine._meta.db_table
        connection = connections[ResponseLine.objects.db]
        adapt = connection.ops.adapt_datetimefield_value
        batch = list(self._buffer)
        rows = [(self.printer_id, seq, adapt(t), x, k) for seq, t, x, k in batch]
        self._buffer.clear()
        sql = (
            f"INSERT INTO {connection.ops.quote_name(table)} "
            "(printer_id, seq, time, text, kind) VALUES (%s, %s, %s, %s, %s)"
        )
        with self._held(), connection.cursor() as cursor:
            cursor.executemany(sql, rows)
        # Published after the commit: a client can always read a gap from the table.
        broadcast.publisher().lines(self.printer_id, batch)

    def discard(self) -> None:
        """Forget unsaved lines (a worker that lost its lease writes nothing more)."""
        self._buffer.clear()

    def _held(self) -> AbstractContextManager[None]:
        if self.lease is None:
            return transaction.atomic()
        return self.lease.held()
