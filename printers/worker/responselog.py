"""Repetier's response log, written in batches so logging never slows the stream.

The worker only writes it: the log is trimmed to the printer's `response_log_limit`
by the upkeep (`printers/upkeep.py`, from Celery beat), never in the worker's loop.
"""

from __future__ import annotations

import logging
import time
from datetime import UTC, datetime
from typing import TYPE_CHECKING

from django.db import connections, transaction
from django.db.models import Max

from printers import broadcast
from printers.dbclock import clock_offset, shared_now
from printers.models import ResponseLine

if TYPE_CHECKING:
    from collections.abc import Callable
    from contextlib import AbstractContextManager

    from django.db.backends.base.base import BaseDatabaseWrapper
    from django.db.backends.utils import CursorWrapper

    from printers.worker.lease import Lease

logger = logging.getLogger("printhost.worker")

#: Flush at least this often (s) and whenever this many lines wait.
FLUSH_SECONDS = 0.25
FLUSH_LINES = 1000
#: Lines held in memory while the database is away (about 50 MB at most).
HELD_LINES = 200_000
#: Lines logged within this long of each other share one timestamp (s): each
#: distinct time costs a datetime and its conversion for the database, and a line
#: and its ok come a few milliseconds apart at most (a hundredth of a second is
#: finer than any log view shows).
STAMP_SECONDS = 0.01


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
        self._stamp_wall = 0.0
        self._stamp_at = shared_now()
        #: The loop's time of the last batch stored by flush_if_due: its transaction
        #: checked the lease (the loop skips its own check right after one).
        self.stored_at = float("-inf")
        #: A batch failed in a way that leaves open whether it went in (the
        #: connection dropped after the server may have committed it): the next
        #: flush asks the table before it writes.
        self._in_doubt = False
        #: PostgreSQL takes this worker's rows by COPY: not where row-level
        #: security keeps a worker host's role to its own printers' rows
        #: (printers/host_role.py), which COPY does not support. Asked once.
        self._copies: bool | None = None

    @property
    def waiting(self) -> int:
        """Lines logged and not stored yet."""
        return len(self._buffer)

    def add(self, text: str, kind: int) -> int:
        """Log one line; returns its id.

        At most HELD_LINES wait for the database; beyond that (a long outage) the
        oldest waiting lines make room, and a note in their place says how many.
        """
        self.last_id += 1
        # The line's time: one datetime for lines within STAMP_SECONDS (aware
        # UTC, as timezone.now() is with USE_TZ, always on, from one reading),
        # by the shared clock (printers/dbclock.py), whose offset is added only
        # when a new datetime is made: this runs twice a line.
        wall = time.time()
        if not 0.0 <= wall - self._stamp_wall < STAMP_SECONDS:
            self._stamp_wall = wall
            self._stamp_at = datetime.fromtimestamp(wall + clock_offset(), UTC)
        self._buffer.append((self.last_id, self._stamp_at, text, int(kind)))
        if len(self._buffer) > HELD_LINES:
            self._drop_oldest()
        return self.last_id

    def _drop_oldest(self) -> None:
        dropped = len(self._buffer) - HELD_LINES // 2
        first, when, _, _ = self._buffer[0]
        del self._buffer[:dropped]
        note = (
            f"[printhost] {dropped} response lines (ids {first} to "
            f"{first + dropped - 1}) were dropped: the database was away too long"
        )
        # The note takes the first dropped id, so ids still only grow.
        self._buffer.insert(0, (first, when, note, 8))

    def flush_if_due(self, now: float) -> None:
        if len(self._buffer) >= FLUSH_LINES or (self._buffer and now >= self._flush_at):
            self.flush()
            self.stored_at = now
        if not self._buffer:
            self._flush_at = now + FLUSH_SECONDS

    def flush(self) -> None:
        """Write every buffered line in one transaction.

        No model instances (bulk_create would make one a line): on PostgreSQL a
        COPY, which costs the worker a quarter of the CPU of an INSERT's
        executemany (7 against 28 us a row, psycopg's binary build), or under
        row-level security one INSERT of the batch as arrays (twice a COPY's
        CPU); elsewhere a plain executemany.

        The buffer is emptied only once the rows are in: while the database is
        away (the lease raises DatabaseAway) they wait here, in order. A batch
        whose connection dropped may still have gone in (the server committed, its
        answer was lost): the next flush first drops the lines the table already
        has, so none is lost and none is stored twice.
        """
        if not self._buffer:
            return
        connection = connections[ResponseLine.objects.db]
        self._in_doubt, was_in_doubt = True, self._in_doubt
        # Errors of the COPY (psycopg's own cursor) as Django's: a dropped
        # connection is an OperationalError, which the lease takes for the
        # database away.
        with (
            self._held(),
            connection.wrap_database_errors,
            connection.cursor() as cursor,
        ):
            if was_in_doubt:
                self._forget_stored(cursor)
            batch = list(self._buffer)
            if batch:
                self._write(connection, cursor, batch)
        self._in_doubt = False
        del self._buffer[: len(batch)]
        if batch:
            # Published after the commit: a client can always read a gap from
            # the table.
            broadcast.publisher().lines(self.printer_id, batch)

    def _forget_stored(self, cursor: CursorWrapper) -> None:
        """Drop from the buffer the lines a batch in doubt did store (only this
        worker writes the printer's log, so the highest stored id says which)."""
        table = cursor.db.ops.quote_name(ResponseLine._meta.db_table)
        cursor.execute(
            f"SELECT MAX(seq) FROM {table} WHERE printer_id = %s", [self.printer_id]
        )
        (stored,) = cursor.fetchone()
        kept = [line for line in self._buffer if line[0] > (stored or 0)]
        if len(kept) < len(self._buffer):
            logger.warning(
                "printer %s: a batch of the response log whose answer was lost "
                "had gone in (%d lines); not storing them twice",
                self.printer_id,
                len(self._buffer) - len(kept),
            )
        self._buffer[:] = kept

    def _write(
        self,
        connection: BaseDatabaseWrapper,
        cursor: CursorWrapper,
        batch: list[tuple[int, datetime, str, int]],
    ) -> None:
        rows = _rows(self.printer_id, batch, connection.ops.adapt_datetimefield_value)
        table = connection.ops.quote_name(ResponseLine._meta.db_table)
        columns = "(printer_id, seq, time, text, kind)"
        if connection.vendor == "postgresql":
            if self._copies is None:
                cursor.execute("SELECT NOT row_security_active(%s)", [table])
                (self._copies,) = cursor.fetchone()
            if self._copies:
                with cursor.cursor.copy(f"COPY {table} {columns} FROM STDIN") as copy:
                    for row in rows:
                        copy.write_row(row)
                return
            cursor.execute(
                f"INSERT INTO {table} {columns} SELECT * FROM unnest(%s::bigint[], "
                "%s::bigint[], %s::timestamptz[], %s::text[], %s::integer[])",
                [list(column) for column in zip(*rows, strict=True)],
            )
        else:
            sql = f"INSERT INTO {table} {columns} VALUES (%s, %s, %s, %s, %s)"
            cursor.executemany(sql, rows)

    def discard(self) -> None:
        """Forget unsaved lines (a worker that lost its lease writes nothing more)."""
        self._buffer.clear()

    def _held(self) -> AbstractContextManager[None]:
        if self.lease is None:
            return transaction.atomic()
        return self.lease.held()


def _rows(
    printer_id: int,
    batch: list[tuple[int, datetime, str, int]],
    adapt: Callable[[datetime], object],
) -> list[tuple[int, int, object, str, int]]:
    """The batch as database rows; each distinct time adapted once (lines share one)."""
    rows = []
    last: datetime | None = None
    adapted: object = None
    for seq, when, text, kind in batch:
        if when is not last:
            last, adapted = when, adapt(when)
        rows.append((printer_id, seq, adapted, text, kind))
    return rows
