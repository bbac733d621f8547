"""Database connections for the long-running loops (workers, fetcher, dispatcher,
runhost).

Requests open and close a connection each (`conn_max_age=0`), as daphne's threads
want. A loop that touches the database ten times a second must not: on
PostgreSQL every connection is a server process, so a printer's worker would start
ten a second. Each turn of these loops calls `close_failed_connections` instead of
Django's `close_old_connections`.
"""

from __future__ import annotations

from django.db import close_old_connections, connections


def close_failed_connections() -> None:
    """`close_old_connections` for a process that lives long: a connection that
    failed (or was left mid-transaction) is closed and the next query opens a new
    one; a healthy one is kept, whatever CONN_MAX_AGE says."""
    for connection in connections.all(initialized_only=True):
        connection.close_at = None
    close_old_connections()
