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

The grants name the worker hosts the role serves, and row-level security keeps its
writes to their rows (`CONFINED`): its own printers' leases, state, jobs, commands,
response log, temperatures and history, its own heartbeat. A shelf computer taken
over cannot start, stop or re-queue a job on another host's printer, answer that
printer's commands or take its lease. It adds no job naming a stored file (the
control plane would serve that file to it) and no file analysis. What it still can
do: read the rows of every printer and job in the columns granted. The tables'
owner (the control plane's role) is not subject to the policies;
`confinement_problem` refuses a host role that is not confined to the host it runs
as, `control_plane_problem` a control plane on a role the policies hold.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from django.db import OperationalError, ProgrammingError, transaction

if TYPE_CHECKING:
    from django.db.backends.base.base import BaseDatabaseWrapper

__all__ = [
    "CONFINED",
    "CONFINED_INSERTS",
    "HOST_PRIVILEGES",
    "BadRoleName",
    "confinement_problem",
    "control_plane_problem",
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
        "INSERT": (),  # an SD upload's print (no stored file: CONFINED_INSERTS)
        "UPDATE": (
            "state", "message", "started_at", "finished_at", "progress_at",
            "lines_sent", "lines_acked", "bytes_acked", "size_bytes",
        ),
    },
    "jobs_historyentry": {
        "SELECT": (),
        "INSERT": (),
        "UPDATE": (),
        "DELETE": (),  # a run the control plane took for dead is forgotten
    },
    "jobs_fileanalysis": {"SELECT": ()},  # a run's figures (jobs/history.py)
    "auth_user": {"SELECT": ("id", "username")},  # the history's "who"
}
# fmt: on
#: What checking an API key reads (printhost/access.py): not a worker host's.
KEY_CHECK: Privileges = {
    table: {"SELECT": ()}
    for table in ("printhost_apikey", "auth_user", "printhost_printerrole")
}

#: The rows a host role may write, table by table, as SQL over `{hosts}` (the
#: quoted names of the hosts it serves); it reads every row its columns allow.
_OWN_HOSTS = "SELECT id FROM printers_workerhost WHERE name IN ({hosts})"
_OWN_PRINTERS = (
    f"SELECT id FROM printers_printer WHERE worker_host_id IN ({_OWN_HOSTS})"
)
CONFINED: dict[str, str] = {
    "printers_printer": f"worker_host_id IN ({_OWN_HOSTS})",
    "printers_workerhost": "name IN ({hosts})",
    **{
        table: f"printer_id IN ({_OWN_PRINTERS})"
        for table in (
            "printers_queuedcommand", "printers_responseline",
            "printers_temperaturesample", "jobs_job", "jobs_historyentry",
        )
    },
}  # fmt: skip
#: What else a host role's new rows must be: a job it adds names no stored file
#: (the control plane serves a host any file its printers' jobs name).
CONFINED_INSERTS = {"jobs_job": "file = ''"}
#: Room in a role's name for its policies' names (`ph_select_<role>`, 63 at most).
_ROLE = re.compile(r"[a-z_][a-z0-9_]{0,52}")
#: A worker host's name (printers/hosts.py): nothing to quote in an SQL string.
_HOST = re.compile(r"[a-z0-9][a-z0-9_-]{0,49}")
_COMMANDS = ("SELECT", "INSERT", "UPDATE", "DELETE")


class BadRoleName(ValueError):
    """A role or worker host name the grants cannot take as it is."""


def grant_statements(role: str, hosts: list[str]) -> list[str]:
    """SQL that takes every privilege *role* has on the schema's tables and gives
    it `HOST_PRIVILEGES`, its writes confined to the rows of *hosts* (for the
    database's owner to run, after each migrate)."""
    if not _ROLE.fullmatch(role):
        raise BadRoleName(
            f"{role!r} is not a plain role name: lower-case letters, digits and _, "
            "not starting with a digit, at most 53"
        )
    if not hosts:
        raise BadRoleName(f"name the worker hosts role {role} serves")
    for host in hosts:
        if not _HOST.fullmatch(host):
            raise BadRoleName(f"{host!r} is not a worker host's name")
    to = f'"{role}"'
    # One transaction: statement by statement, the role would be without its
    # grants or policies for a moment, and its hosts' running prints would fail.
    statements = [
        "BEGIN;",
        f"REVOKE ALL ON ALL TABLES IN SCHEMA public FROM {to};",
        f"REVOKE ALL ON ALL SEQUENCES IN SCHEMA public FROM {to};",
        f"GRANT USAGE ON SCHEMA public TO {to};",
    ]
    for table, privileges in HOST_PRIVILEGES.items():
        for privilege, columns in privileges.items():
            what = f"{privilege} ({', '.join(columns)})" if columns else privilege
            statements.append(f"GRANT {what} ON {table} TO {to};")
    names = ", ".join(f"'{host}'" for host in sorted(set(hosts)))
    for table, rows in CONFINED.items():
        own = rows.format(hosts=names)
        statements.append(f"ALTER TABLE {table} ENABLE ROW LEVEL SECURITY;")
        for command in _COMMANDS:
            policy = f'"ph_{command.lower()}_{role}"'
            statements.append(f"DROP POLICY IF EXISTS {policy} ON {table};")
            if command == "SELECT":
                rule = "USING (true)"
            elif command not in HOST_PRIVILEGES[table]:
                continue
            elif command == "INSERT":
                extra = CONFINED_INSERTS.get(table)
                rule = f"WITH CHECK ({own}{f' AND {extra}' if extra else ''})"
            elif command == "DELETE":
                rule = f"USING ({own})"
            else:
                rule = f"USING ({own}) WITH CHECK ({own})"
            statements.append(
                f"CREATE POLICY {policy} ON {table} FOR {command} TO {to} {rule};"
            )
    return [*statements, "COMMIT;"]


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


def confinement_problem(connection: BaseDatabaseWrapper, host: str) -> str | None:
    """Why the connection's role may not run as worker host *host*: its writes
    reach other hosts' rows (grants without policies, or from before them), or
    its policies name other hosts. None when they are *host*'s rows, off
    PostgreSQL, and for the tables' owner or a superuser (a farm on one role)."""
    if connection.vendor != "postgresql":
        return None
    tables = list(CONFINED)
    with connection.cursor() as cursor:
        cursor.execute(
            "SELECT current_user, rolsuper OR rolbypassrls OR bool_and("
            "pg_has_role(current_user, tableowner, 'USAGE')) "
            "FROM pg_roles, pg_tables WHERE rolname = current_user "
            "AND schemaname = current_schema() AND tablename = ANY(%s) "
            "GROUP BY rolsuper, rolbypassrls",
            [tables],
        )
        row = cursor.fetchone()
        if row is None or row[1]:
            return None
        role = row[0]
        cursor.execute(
            "SELECT t FROM unnest(%s::text[]) AS t WHERE NOT row_security_active(t)",
            [tables],
        )
        unconfined = [table for (table,) in cursor.fetchall()]
    again = (
        "As the database's owner, run the SQL of "
        f"`manage.py worker_host grants {role} {host}`"
    )
    if unconfined:
        return (
            f"the database role {role!r} may write other hosts' rows of "
            f"{', '.join(unconfined)}. {again}"
        )
    with transaction.atomic(using=connection.alias):
        with connection.cursor() as cursor:
            # Its own heartbeat row is the one row of printers_workerhost it may
            # write: an update that changes nothing, undone, asks the policy.
            cursor.execute(
                "UPDATE printers_workerhost SET seen_at = seen_at WHERE name = %s",
                [host],
            )
            writable = cursor.rowcount
            cursor.execute("SELECT 1 FROM printers_workerhost WHERE name = %s", [host])
            exists = cursor.fetchone() is not None
        transaction.set_rollback(True, using=connection.alias)
    if exists and not writable:
        return (
            f"the database role {role!r} serves other worker hosts than {host}. {again}"
        )
    return None


def control_plane_problem(connection: BaseDatabaseWrapper) -> str | None:
    """Why a control plane may not run on the connection's role: the worker hosts'
    row policies apply to it (a role that does not own the tables), so it would see
    none of the farm's printers and jobs. None when they do not, off PostgreSQL, and
    while the database is away or not migrated yet (nothing to go by)."""
    if connection.vendor != "postgresql":
        return None
    try:
        with connection.cursor() as cursor:
            cursor.execute(
                "SELECT current_user, row_security_active('printers_printer')"
            )
            role, bound = cursor.fetchone()
    except (OperationalError, ProgrammingError):
        return None
    if not bound:
        return None
    return (
        f"the database role {role!r} is held to worker hosts' rows (row-level "
        "security applies to it: it does not own the tables); the control plane "
        "connects as the role that owns them (docs/deploy.md, section 2)"
    )
