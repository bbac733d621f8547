"""A worker's claim on its printer: a row lease taken with a conditional UPDATE.

Every write the worker makes for its printer (job outcome and progress, printer
state, response log) runs in `Lease.held()`: one transaction that first touches the
printer row on the condition that this worker still holds an unexpired lease. That
row lock (PostgreSQL) or write lock (SQLite) is kept until the commit, so a takeover
is ordered strictly before or after the write: after it, the write is refused.

Locally the worker also knows how long its lease surely lasts (`valid_until`, counted
from before the renewing UPDATE), and touches the port only inside that time.

**Whose clock.** The expiry is written and compared by the database's clock
(`printers/dbclock.py`), in the very statements that take, renew and check the
lease; the reaper and the dispatcher judge it by the same clock. No computer's own
wall clock enters it: a host whose clock is off, or stepped by NTP mid-print,
neither loses a printer it renews nor keeps a dead one looking alive. `valid_until`
counts on this computer's monotonic clock, which nothing steps.

**The database away.** A worker that holds its port (`portlock`, `keep_while_away`)
keeps driving its printer while the database does not answer: no other worker on
its computer can open the port, and no worker on another host may claim the
printer (`claim`). Every database call then raises `DatabaseAway` at once instead
of waiting (the loop keeps streaming and holds what it would write); every
`RETRY_FIRST` s, doubling to `RETRY_CAP`, the next call tries to renew the lease
first, and once that succeeds (`recovered`) the worker writes what it held, in
order. A renewal only extends a lease that still names this worker, expired or
not: nobody else can have taken it meanwhile, and if somebody did, the worker
lets go (LeaseLost).
"""

from __future__ import annotations

import logging
import os
import socket
import time
import uuid
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

from django.conf import settings
from django.db import (
    InterfaceError,
    OperationalError,
    close_old_connections,
    connections,
    transaction,
)
from django.db.models import Q
from django.db.models.functions import Now

from printers.dbclock import now_plus, now_sql
from printers.models import Printer

if TYPE_CHECKING:
    from collections.abc import Iterator

logger = logging.getLogger("printhost.worker")

#: Renew this many times per lease period (a renewal that waits behind a slow write
#: or a lock still has most of the period left).
RENEWALS_PER_LEASE = 5
#: While the database is away, try it again after this long (s), doubling to the cap.
RETRY_FIRST = 0.5
RETRY_CAP = 5.0
#: What a database that went away raises (a refused or broken connection).
UNREACHABLE = (OperationalError, InterfaceError)


def make_owner() -> str:
    """A name for this worker that says where it runs: host:pid:random."""
    return f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:6]}"


class LeaseLost(Exception):
    """Another worker holds the printer; this one must stop driving it."""


class DatabaseAway(Exception):
    """The database does not answer: the write waits until it is back."""


class Lease:
    """Two workers can never drive one printer: whoever renews in time keeps it."""

    def __init__(
        self, printer_id: int, owner: str, seconds: float, host: str | None = None
    ) -> None:
        self.printer_id = printer_id
        #: The worker host this worker runs on ("" = the control plane's runhost);
        #: runhost tells its workers (PRINTHOST_WORKER_HOST).
        self.host = settings.PRINTHOST_WORKER_HOST if host is None else host
        self.owner = owner
        self.seconds = seconds
        self.renew_at = 0.0
        #: Monotonic time until which the lease surely holds (0: not held).
        self.valid_until = 0.0
        self.lost = False
        #: The worker holds the port (run_printer's PortLock): it keeps driving the
        #: printer while the database is away. Without it a database error ends it.
        self.keep_while_away = False
        #: Monotonic time the database stopped answering (None: it answers).
        self.away_since: float | None = None
        #: Set when the database answers again; the worker clears it once it wrote
        #: what it held.
        self.recovered = False
        self._retry_at = 0.0
        self._retry_delay = RETRY_FIRST

    def claim(self) -> bool:
        """Take the printer if it is free, expired or already ours (one UPDATE),
        and only if it belongs to this worker's host: a printer is never handed
        to a worker on another computer, whose port is not that printer. Expiry
        is the database's time (`printers/dbclock.py`), never this computer's."""
        free = (
            Q(lease_owner="")
            | Q(lease_owner=self.owner)
            | Q(lease_expires_at__lt=Now())
        )
        won = (
            Printer.objects.filter(pk=self.printer_id)
            .filter(free, self._on_this_host())
            .update(
                lease_owner=self.owner,
                lease_expires_at=now_plus(self.seconds),
                worker_seen_at=Now(),
            )
        )
        return won == 1

    def _on_this_host(self) -> Q:
        if self.host:
            return Q(worker_host__name=self.host)
        return Q(worker_host__isnull=True)

    def _refusal(self) -> str:
        """Why a claim failed: another worker holds it, or it is another host's."""
        row = (
            Printer.objects.filter(pk=self.printer_id)
            .values_list("lease_owner", "worker_host__name")
            .first()
        )
        owner, host = row or ("", None)
        if (host or "") != self.host:
            where = f"worker host {host}" if host else "the control plane's runhost"
            here = f"worker host {self.host}" if self.host else "no worker host"
            return f"printer {self.printer_id} is driven from {where}, not from {here}"
        if owner == self.owner:
            # Its row still names this worker, yet the write found no row: the
            # database role's row policies no longer cover this host.
            return (
                f"printer {self.printer_id}: this worker's database role may no "
                f"longer write its row (the worker host's grants: manage.py "
                f"worker_host grants ROLE {self.host or 'HOST'})"
            )
        return f"printer {self.printer_id} is now driven by {owner or 'nobody'}"

    def _extend(self) -> bool:
        """Renew: only while the row still names this worker (never re-take it)."""
        return (
            Printer.objects.filter(pk=self.printer_id, lease_owner=self.owner).update(
                lease_expires_at=now_plus(self.seconds), worker_seen_at=Now()
            )
            == 1
        )

    def holder(self) -> str:
        return (
            Printer.objects.filter(pk=self.printer_id)
            .values_list("lease_owner", flat=True)
            .first()
            or ""
        )

    @property
    def away(self) -> bool:
        return self.away_since is not None

    def _went_away(self, error: Exception) -> DatabaseAway:
        now = time.monotonic()
        if self.away_since is None:
            self.away_since = now
            self._retry_delay = RETRY_FIRST
            logger.warning(
                "printer %s: the database does not answer (%s); streaming on, "
                "holding what is to be written",
                self.printer_id,
                str(error).strip().splitlines()[0] if str(error).strip() else error,
            )
        else:
            self._retry_delay = min(self._retry_delay * 2, RETRY_CAP)
        self._retry_at = now + self._retry_delay
        return DatabaseAway(f"printer {self.printer_id}: the database does not answer")

    def unreachable(self, error: Exception) -> DatabaseAway:
        """A database call outside `held()` failed because the database went away."""
        return self._went_away(error)

    def _not_yet(self) -> None:
        """While away, refuse at once until the next try is due."""
        if self.away_since is not None and time.monotonic() < self._retry_at:
            raise DatabaseAway(f"printer {self.printer_id}: the database is away")

    def take(self, now: float) -> None:
        """Claim or renew at monotonic time *now* (read before the UPDATE)."""
        if self.lost:
            raise LeaseLost(f"printer {self.printer_id}: this worker lost its lease")
        self._not_yet()
        try:
            if self.away_since is not None:
                close_old_connections()
            won = self._extend() if self.valid_until else self.claim()
        except UNREACHABLE as error:
            raise self._went_away(error) from None
        if self.away_since is not None and won:
            logger.warning(
                "printer %s: the database answers again after %.1f s; writing what "
                "was held",
                self.printer_id,
                time.monotonic() - self.away_since,
            )
            self.away_since = None
            self.recovered = True
        if not won:
            self.lost = True
            raise LeaseLost(self._refusal())
        self.valid_until = now + self.seconds
        self.renew_at = now + self.seconds / RENEWALS_PER_LEASE

    def renew_if_due(self, now: float) -> None:
        """Renew a fifth of the way through; raise LeaseLost if someone else has it
        (DatabaseAway if the database does not answer)."""
        if now >= self.renew_at or self.away_since is not None:
            self.take(now)

    def renew_now(self, now: float) -> None:
        """Renew at once, even before the next try after an outage is due (a
        stopping worker has no later turn to wait for)."""
        self._retry_at = 0.0
        self.take(now)

    def ensure(self, now: float) -> None:
        """Before touching the port: renew at once if the lease may have run out.

        While the database is away a worker that holds its port goes on: the port
        is the printer, and nobody else can have it (see the module's docstring).
        """
        if self.lost:
            raise LeaseLost(f"printer {self.printer_id}: this worker lost its lease")
        if now >= self.valid_until:
            try:
                self.take(now)
            except DatabaseAway:
                if not self.keep_while_away:
                    raise

    def check(self) -> None:
        """A read: raise LeaseLost unless the row still names this worker, unexpired.

        Cheap enough for every poll; it narrows (the conditional writes in `held()`
        close) the window in which a worker could act after a takeover.
        """
        if self.lost:
            raise LeaseLost(f"printer {self.printer_id}: this worker lost its lease")
        if self.away_since is not None:
            raise DatabaseAway(f"printer {self.printer_id}: the database is away")
        try:
            mine = self._still_mine()
        except UNREACHABLE as error:
            raise self._went_away(error) from None
        if not mine:
            self.lost = True
            raise LeaseLost(
                f"printer {self.printer_id}: lease lost "
                f"(now held by {self.holder() or 'nobody'})"
            )

    def _still_mine(self) -> bool:
        """The row names this worker, unexpired: one indexed read."""
        return self._on_my_row("SELECT 1 FROM {table}") == 1

    def _seen(self, columns: dict[str, Any] | None = None) -> int:
        """Within a transaction: note the worker was seen, on its row only while it
        still holds the lease, and lock the row (1) or find it is not (0). The row's
        *columns* (field name: value) are written by the same statement."""
        db = connections[Printer.objects.db]
        head, values = "UPDATE {table} SET worker_seen_at = {now}", []
        for name, value in (columns or {}).items():
            field = Printer._meta.get_field(name)
            head += f", {db.ops.quote_name(field.column)} = %s"
            values.append(field.get_db_prep_save(value, connection=db))
        return self._on_my_row(head, stamp=True, values=values)

    def _on_my_row(
        self, head: str, *, stamp: bool = False, values: list[Any] | None = None
    ) -> int:
        """Run *head* (a SELECT or UPDATE of `{table}`, `{now}` the database's
        time; with *stamp*, its `%s` are *values*) on the printer's row while it
        names this worker, unexpired by the database's clock; how many rows it
        found. Plain SQL: an idle worker checks every second and every batch of
        the log writes, and the ORM's query cost several times the database's
        answer (1.6 ms against 0.1 ms here)."""
        db = connections[Printer.objects.db]
        table = db.ops.quote_name(Printer._meta.db_table)
        now = now_sql(db.vendor)
        sql = (
            head.format(table=table, now=now)
            + f" WHERE id = %s AND lease_owner = %s AND lease_expires_at > {now}"
        )
        params = list(values or []) if stamp else []
        with db.cursor() as cursor:
            cursor.execute(sql, [*params, self.printer_id, self.owner])
            return cursor.rowcount if stamp else len(cursor.fetchall())

    @contextmanager
    def held(self, **columns: Any) -> Iterator[None]:
        """A transaction that commits only while this worker holds the lease.

        *columns*: fields of the printer's row written by the lease's own check
        (one statement: the status a worker saves every second).
        DatabaseAway (nothing written) while the database does not answer; the
        first call after that renews the lease before it writes.
        """
        if self.lost:
            raise LeaseLost(f"printer {self.printer_id}: this worker lost its lease")
        if self.away_since is not None:
            self.take(time.monotonic())  # DatabaseAway until it answers again
        try:
            with self._written(columns):
                yield
        except UNREACHABLE as error:
            raise self._went_away(error) from None

    @contextmanager
    def _written(self, columns: dict[str, Any]) -> Iterator[None]:
        with transaction.atomic():
            if self._seen(columns) != 1:
                self.lost = True
                raise LeaseLost(f"lease lost: {self._refusal()}")
            yield

    def release(self) -> None:
        Printer.objects.filter(pk=self.printer_id, lease_owner=self.owner).update(
            lease_owner="", lease_expires_at=None
        )
        self.valid_until = 0.0
