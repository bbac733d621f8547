"""The database's clock: the one clock every computer of a farm shares.

A printer's lease is written and judged by it alone (`printers/worker/lease.py`,
the reaper, the dispatcher). Each computer has its own wall clock: one a few
seconds off would see a lease run out that its holder still renews, or keep a
dead host's printer looking alive; a small board without a battery-backed clock
starts minutes off and is stepped by NTP later, mid-print. The database's clock
is read where the lease's row is, in the same statement.

What a worker stamps with a time of its own (a job's start, end and progress, the
response log's lines, a request's answer, a temperature reading) is stamped by
the shared clock as this computer reckons it (`shared_now`, `shared_time`): its
own clock plus the offset it last measured against the database's
(`learn_offset`, at a worker's start and every OFFSET_CHECK_SECONDS, and with
each worker host's heartbeat, which shows it). A board an hour off after a power
cut, before NTP steps it, then still shows its prints' elapsed times, history and
log in the farm's time. An offset under OFFSET_NEGLIGIBLE is taken as none: a
computer kept by NTP is closer than reading it can tell.

What judges those stamps by the time now (a host's heartbeat age and whether it
is online, a job's elapsed time and ETA, the metrics) reads `shared_now` too. A
web server, which may run on another computer than the database, learns its
offset as it goes (`learn_offset_if_due` before a request, at most every
OFFSET_CHECK_SECONDS; printhost/shared_clock.py): one a minute off would
otherwise show every worker host offline.
"""

from __future__ import annotations

import contextlib
import time
from datetime import UTC, datetime, timedelta

from django.db import DEFAULT_DB_ALIAS, DatabaseError, connections
from django.db.models import DateTimeField, ExpressionWrapper
from django.db.models.functions import Now
from django.utils import timezone

__all__ = [
    "clock_offset",
    "database_now",
    "learn_offset",
    "learn_offset_if_due",
    "now_plus",
    "now_sql",
    "offset_due",
    "shared_now",
    "shared_time",
]

#: Seconds between a worker's readings of the database's clock.
OFFSET_CHECK_SECONDS = 60.0
#: A reading whose round trip took longer than this (s) is not trusted: the
#: database's time could be anywhere in it.
OFFSET_TRUST_ROUND_TRIP = 0.25
#: An offset smaller than this (s) is taken as none.
OFFSET_NEGLIGIBLE = 0.5

#: The database's clock minus this computer's (s), as last measured.
_offset = 0.0
#: When this process last read the database's clock (monotonic; -inf: never).
_learned_at = float("-inf")


def now_sql(vendor: str, *, with_params: bool = True) -> str:
    """SQL for the database's time now, as a DateTimeField column holds it.

    *with_params*: the statement has parameters, so a `%` is written `%%`.
    """
    if vendor == "postgresql":
        return "statement_timestamp()"
    if vendor == "sqlite":  # UTC text, as Django stores times there
        sql = "STRFTIME('%%Y-%%m-%%d %%H:%%M:%%f', 'NOW')"
        return sql if with_params else sql.replace("%%", "%")
    return "CURRENT_TIMESTAMP"


def now_plus(seconds: float) -> ExpressionWrapper:
    """The database's time now plus *seconds*, for an ORM update."""
    return ExpressionWrapper(
        Now() + timedelta(seconds=seconds), output_field=DateTimeField()
    )


def database_now(alias: str = DEFAULT_DB_ALIAS) -> datetime:
    """The database's time now (aware, UTC)."""
    db = connections[alias]
    with db.cursor() as cursor:
        cursor.execute(f"SELECT {now_sql(db.vendor, with_params=False)}")
        (value,) = cursor.fetchone()
    if isinstance(value, str):
        value = datetime.fromisoformat(value)
    if value.tzinfo is None:
        value = value.replace(tzinfo=UTC)
    return value


def learn_offset(alias: str = DEFAULT_DB_ALIAS) -> float | None:
    """Read the database's clock and keep how far this computer's is from it (for
    `shared_now`); returns the offset measured (s), or None when the round trip
    was too slow to tell. Raises what the query raises (the database away)."""
    global _offset, _learned_at  # one clock per process
    _learned_at = time.monotonic()
    before = time.time()
    shared = database_now(alias).timestamp()
    after = time.time()
    if after - before > OFFSET_TRUST_ROUND_TRIP:
        return None
    measured = shared - (before + after) / 2
    _offset = measured if abs(measured) >= OFFSET_NEGLIGIBLE else 0.0
    return measured


def clock_offset() -> float:
    """The database's clock minus this computer's (s), as last learned (0 when
    negligible or never measured)."""
    return _offset


def shared_time() -> float:
    """Seconds since the epoch by the shared clock, as this computer reckons it."""
    return time.time() + _offset


def shared_now() -> datetime:
    """The time now by the shared clock, as this computer reckons it (aware)."""
    now = timezone.now()
    return now + timedelta(seconds=_offset) if _offset else now


def offset_due() -> bool:
    """This process has not read the database's clock for OFFSET_CHECK_SECONDS."""
    return time.monotonic() - _learned_at >= OFFSET_CHECK_SECONDS


def learn_offset_if_due() -> None:
    """`learn_offset` when this process has not read the database's clock for
    OFFSET_CHECK_SECONDS (one query a minute at most; not in an event loop).
    While the database is away the offset last learned stands, and the next try
    waits as long. Never in a worker's loop: a database that does not answer
    would hold its stream up (the worker learns on its own turns)."""
    if not offset_due():
        return
    # The database away: the request that follows meets it and says so.
    with contextlib.suppress(DatabaseError):
        learn_offset()
