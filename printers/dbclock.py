"""The database's clock: the one clock every computer of a farm shares.

A printer's lease is written and judged by it alone (`printers/worker/lease.py`,
the reaper, the dispatcher). Each computer has its own wall clock: one a few
seconds off would see a lease run out that its holder still renews, or keep a
dead host's printer looking alive; a small board without a battery-backed clock
starts minutes off and is stepped by NTP later, mid-print. The database's clock
is read where the lease's row is, in the same statement.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

from django.db import DEFAULT_DB_ALIAS, connections
from django.db.models import DateTimeField, ExpressionWrapper
from django.db.models.functions import Now

__all__ = ["database_now", "now_plus", "now_sql"]


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
