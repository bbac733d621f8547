"""PostgreSQL tells a worker that something was written for its printer.

A request (`QueuedCommand`) or a job queued for a printer fires `pg_notify` on the
channel `printhost_printer_<id>` (triggers in jobs/migrations/0010); the worker
LISTENs on its own database connection and waits on that socket beside the
serial port. It reads the database when told to, and otherwise only every
`PRINTHOST_FALLBACK_POLL_SECONDS`, instead of ten times a second: most of what an
idle farm spent, on the worker hosts and on PostgreSQL.

SQLite has no notifications. A worker in a process of its own (*alone*) waits on
its doorbell instead (printers/doorbell.py: a named pipe the writers of its
requests and jobs ring at commit) and polls as rarely as when it LISTENs; a
worker that shares its connection (tests drive one in their own thread, inside
transactions that never commit) has no doorbell: `fileno()` is None and it polls
every `PRINTHOST_POLL_SECONDS`. On SQLite, before each poll's reads it asks
SQLite whether anyone else wrote since the last one (`quiet()`: `PRAGMA
data_version` counts other connections' commits); when nobody did, the
requests, the jobs and the lease are as they were, and the reads are skipped
(at most FALLBACK_SECONDS in a row). A worker that shares its connection (tests
drive one in their own thread) counts that connection's writes too
(`total_changes`), its own among them. A notification can be lost
(the connection dropped, the database restarted); a new connection is LISTENed on
again and counts as a wake-up, and the fallback poll bounds any other miss.
"""

from __future__ import annotations

import logging
import time
from typing import Any

from django.db import connections

from printers.doorbell import Doorbell

__all__ = ["SqliteWrites", "Wakeups", "channel_for"]

logger = logging.getLogger("printhost.worker")

#: After a failed LISTEN (the database away) the next try waits this long (s).
RETRY_SECONDS = 1.0
#: SQLite: the poll reads at least this often even when nothing was written (s).
FALLBACK_SECONDS = 1.0


def channel_for(printer_id: int) -> str:
    """The notification channel of one printer (what the triggers name)."""
    return f"printhost_printer_{int(printer_id)}"


class Wakeups:
    """LISTEN for one printer on the worker's database connection."""

    def __init__(
        self, printer_id: int, *, alias: str = "default", alone: bool = False
    ) -> None:
        self.channel = channel_for(printer_id)
        self.alias = alias
        #: The psycopg connection LISTENed on (None: none yet, or not PostgreSQL).
        self._listening: Any = None
        #: Set by a notification psycopg read during a query of the worker's own.
        self._heard = False
        self._retry_at = 0.0
        #: Only PostgreSQL notifies (asked once: the loop asks for fileno() every turn).
        vendor = connections[alias].vendor
        self._notifying = vendor == "postgresql"
        #: SQLite: what was written since the poll last read (`quiet()`).
        self._writes = SqliteWrites(alone=alone) if vendor == "sqlite" else None
        #: SQLite, a worker process of its own: the doorbell its writers ring.
        self._bell = Doorbell(printer_id) if vendor == "sqlite" and alone else None
        if self._bell is not None:
            self._heard = True  # what was written before the pipe is read at once

    @property
    def listening(self) -> bool:
        """A LISTEN (or a doorbell) is in place: the worker may poll rarely."""
        if self._bell is not None:
            return self._bell.fileno() is not None
        raw = self._listening
        return raw is not None and not raw.closed

    def fileno(self) -> int | None:
        """The socket (or pipe) to wait on, LISTENing on the current connection
        first; None when there is nothing to wait on (no LISTEN or doorbell, no
        connection yet)."""
        if self._bell is not None:
            return self._bell.fileno()
        if not self._notifying:
            return None
        wrapper = connections[self.alias]
        raw = wrapper.connection
        if raw is None or raw.closed:
            return None
        if raw is not self._listening:
            now = time.monotonic()
            if now < self._retry_at:
                return None
            try:
                self._listen(wrapper, raw)
            except Exception as error:  # the database is away: poll meanwhile
                logger.debug("LISTEN %s failed: %r", self.channel, error)
                self._retry_at = now + RETRY_SECONDS
                return None
            if raw is not self._listening:
                return None
        try:
            return raw.pgconn.socket
        except Exception:
            return None

    def _listen(self, wrapper: Any, raw: Any) -> None:
        if wrapper.in_atomic_block:
            return  # LISTEN would wait for the commit; the next call does it
        with wrapper.cursor() as cursor:
            cursor.execute(f"LISTEN {self.channel}")
        raw.add_notify_handler(self._on_notify)
        self._listening = raw
        # Whatever was written while there was no LISTEN is looked for now.
        self._heard = True

    def _on_notify(self, notify: Any) -> None:
        if notify.channel == self.channel:
            self._heard = True

    def take(self, *, readable: bool) -> bool:
        """Whether a notification came since the last call; *readable*: the socket
        was, so what it holds is read first (without waiting)."""
        if self._bell is not None:
            heard, self._heard = self._heard, False
            return (readable and self._bell.drain()) or heard
        raw = self._listening
        if readable and raw is not None and not raw.closed:
            try:
                raw.pgconn.consume_input()
                while (notify := raw.pgconn.notifies()) is not None:
                    if notify.relname.decode() == self.channel:
                        self._heard = True
            except Exception as error:  # a broken connection: Django reopens it
                logger.debug("notifications on %s: %r", self.channel, error)
                self._listening = None
                self._heard = True
        heard, self._heard = self._heard, False
        return heard

    def close(self) -> None:
        """The worker stops: remove its doorbell (a LISTEN ends with its connection)."""
        if self._bell is not None:
            self._bell.close()

    def quiet(self, now: float) -> bool:
        """SQLite: nobody wrote since the poll last read (SqliteWrites), so it
        need not read now. Always False on other databases."""
        if self._writes is None:
            return False
        return self._writes.quiet(connections[self.alias].connection, now)


class SqliteWrites:
    """Whether an SQLite database was written since the last look.

    `PRAGMA data_version` changes when another connection commits; a worker
    that is not *alone* on its connection (a test drives it in its own thread)
    counts that connection's changes too (`total_changes`).
    """

    def __init__(self, *, alone: bool) -> None:
        #: Nobody else writes on the worker's connection (a process of its
        #: own): the writes there are the worker's, never a request.
        self.alone = alone
        #: The connection, its data_version and total_changes at the last look.
        self._seen: tuple[Any, int, int] | None = None
        self._read_at = float("-inf")

    def quiet(self, raw: Any, now: float) -> bool:
        """Nothing written since the last call on *raw* (sqlite3.Connection) and
        a read within FALLBACK_SECONDS: the caller may skip its reads. False
        for a new connection, or one that cannot answer."""
        seen, self._seen = self._seen, None
        if raw is None:
            return False
        try:
            (version,) = raw.execute("PRAGMA data_version").fetchone()
            self._seen = (raw, version, 0 if self.alone else raw.total_changes)
        except Exception as error:  # a closed connection: read as usual
            logger.debug("data_version: %r", error)
            return False
        if self._seen != seen or now - self._read_at >= FALLBACK_SECONDS:
            self._read_at = now
            return False
        return True
