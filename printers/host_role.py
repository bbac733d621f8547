"""A worker host's own PostgreSQL role: the privileges its workers need, and no more.

A worker host sits on a shelf next to its printers; with the farm's own database
credentials, whoever takes over that computer could read every user's password
hash, write API keys and roles, rewrite another printer's start script or queue
G-code for it. A role granted only `HOST_PRIVILEGES` can do what a worker host
does (claim and renew its printers' leases, beat, take and answer their commands,
append their response log and temperatures, move its jobs on and write their
history) and nothing else: no authentication tables beyond a user's name, no
printer settings, no new commands, no job's file or requirements.

`manage.py worker_host grants ROLE` prints the SQL that gives a role these
privileges (run it as the database's owner after each `migrate`); `runhost
--worker-host` checks them before it starts a worker (`missing_privileges`), so a
role short of one is refused with the GRANT to run, not found out mid-print.

What such a role still can do: change the state and progress of any printer's jobs
and commands and the leases of any printer (the database cannot tell one host's
rows from another's), and start a stored file on a printer through `[ESP700]`.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from django.db.backends.base.base import BaseDatabaseWrapper

__all__ = [
    "HOST_PRIVILEGES",
    "BadRoleName",
    "grant_statements",
    "missing_privileges",
    "reads_keys",
]

Privileges = dict[str, dict[str, tuple[str, ...]]]

#: Per table, per privilege: the columns it covers (empty: the whole table).
#: printers/worker, printers/heartbeat.py, printers/fetcher.py and jobs/history.py
#: are what reads and writes them.
# fmt: off
HOST_PRIVILEGES: Privileges = {
    "printers_printer": {
        "SELECT": (),
        "UPDATE": (
            "lease_owner", "lease_expires_at", "worker_seen_at", "state",
            "state_message", "emergency_halt", "firmware_name", "capabilities",
            "temperatures", "machine_status", "sd_card", "link_stats",
        ),
    },
    "printers_workerhost": {
        "SELECT": (),  # key_hash too: a digest of a random key, of no use to have
        # Never the name or key: a host cannot take another's place.
        "UPDATE": (
            "instance", "hostname", "version", "started_at", "seen_at", "load",
            "printers", "metrics_address",
        ),
    },
    "printers_queuedcommand": {
        "SELECT": (),
        "UPDATE": ("state", "reply", "done_at"),
    },
    "printers_responseline": {
        "SELECT": ("printer_id", "seq"),
        "INSERT": ("printer_id", "seq", "time", "text", "kind"),
    },
    "printers_temperaturesample": {
        "SELECT": ("id",),  # INSERT ... RETURNING id
        "INSERT": ("printer_id", "time", "temperatures"),
    },
    "jobs_job": {
        "SELECT": (),
        "INSERT": (),  # [ESP700]stream= and an SD upload's print
        "UPDATE": (
            "state", "message", "started_at", "finished_at", "progress_at",
            "lines_sent", "lines_acked", "bytes_acked", "size_bytes", "analysis_id",
        ),
    },
    "jobs_historyentry": {
        "SELECT": (),
        "INSERT": (),
        "UPDATE": (),
        "DELETE": (),  # a run the control plane took for dead is forgotten
    },
    "jobs_fileanalysis": {
        "SELECT": (),
        "INSERT": (),  # [ESP700]stream= asks for an analysis
        "UPDATE": ("sent_at",),
    },
    "auth_user": {"SELECT": ("id", "username")},  # the history's "who"
}
# fmt: on
#: What checking an API key reads (printhost/access.py): not a worker host's.
KEY_CHECK: Privileges = {
    table: {"SELECT": ()}
    for table in ("printhost_apikey", "auth_user", "printhost_printerrole")
}

_ROLE = re.compile(r"[a-z_][a-z0-9_]{0,62}")


class BadRoleName(ValueError):
    """Not a plain PostgreSQL role name."""


def grant_statements(role: str) -> list[str]:
    """SQL that takes every privilege *role* has on the schema's tables and gives
    it `HOST_PRIVILEGES` (for the database's owner to run, after each migrate)."""
    if not _ROLE.fullmatch(role):
        raise BadRoleName(
            f"{role!r} is not a plain role name: lower-case letters, digits and _, "
            "not starting with a digit, at most 63"
        )
    to = f'"{role}"'
    statements = [
        f"REVOKE ALL ON ALL TABLES IN SCHEMA public FROM {to};",
        f"REVOKE ALL ON ALL SEQUENCES IN SCHEMA public FROM {to};",
        f"GRANT USAGE ON SCHEMA public TO {to};",
    ]
    for table, privileges in HOST_PRIVILEGES.items():
        for privilege, columns in privileges.items():
            what = f"{privilege} ({', '.join(columns)})" if columns else privilege
            statements.append(f"GRANT {what} ON {table} TO {to};")
    return statements


def missing_privileges(
    connection: BaseDatabaseWrapper, wanted: Privileges = HOST_PRIVILEGES
) -> list[str]:
    """The privileges of *wanted* the connection's role lacks, as GRANT fragments
    ("UPDATE (state) ON jobs_job"); none off PostgreSQL (SQLite has no roles)."""
    if connection.vendor != "postgresql":
        return []
    checks: list[tuple[str, str, str]] = []
    for table, privileges in wanted.items():
        for privilege, columns in privileges.items():
            checks.extend((table, privilege, column) for column in columns or ("",))
    query = " UNION ALL ".join(
        "SELECT %s, %s, %s, "
        + (
            "has_column_privilege(%s, %s, %s)"
            if column
            else "has_table_privilege(%s, %s)"
        )
        for _, _, column in checks
    )
    params: list[str] = []
    for table, privilege, column in checks:
        params += [table, privilege, column, table]
        params += [column, privilege] if column else [privilege]
    with connection.cursor() as cursor:
        cursor.execute(query, params)
        rows = cursor.fetchall()
    return [
        f"{privilege} ({column}) ON {table}" if column else f"{privilege} ON {table}"
        for table, privilege, column, held in rows
        if not held
    ]


def reads_keys(connection: BaseDatabaseWrapper) -> bool:
    """The connection's role may check an API key (its key, user and roles): a
    role granted only HOST_PRIVILEGES may not, so its metrics need the token."""
    return not missing_privileges(connection, KEY_CHECK)
