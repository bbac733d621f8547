"""A control plane and a worker host as separate installations on one PostgreSQL,
the host on its own role granted only what `worker_host grants` prints: the host
runs its printer, fetches the job's file over HTTP and prints it exactly, with its
log, temperatures, heartbeat and history; the control plane drives no printer. The
role can read no password or key, change no printer's settings and queue no
command, and writes no row of another host's printers; runhost refuses a role
short of a grant, or not kept to its own host's rows, before it drives anything."""

from __future__ import annotations

import json
import uuid
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

import httpx
import pytest

from printers.sample_gcode import commands_of, segments
from tests.conftest import HOST_COMMANDS, wait_for
from tests.hosts import Host, free_port, import_or_skip, postgres_url
from tests.ops.conftest import samples
from tests.printers.test_response_log_postgres import AWKWARD

pytestmark = [pytest.mark.slow, pytest.mark.services]

ADMIN = "postgresql://postgres@127.0.0.1:5432/postgres"


def _as_role(url: str, role: str) -> str:
    parts = urlsplit(url)
    return urlunsplit(parts._replace(netloc=f"{role}@{parts.hostname}:{parts.port}"))


@pytest.fixture
def farm(tmp_path: Path) -> Iterator[tuple[Host, Host, str]]:
    """A migrated control plane, a worker host `shelf-1` with printer p1 and its
    key, and a login role of no privileges (dropped after the test)."""
    psycopg = import_or_skip("psycopg")
    database = postgres_url()
    role = f"ph_host_{uuid.uuid4().hex[:8]}"
    with psycopg.connect(ADMIN, autocommit=True) as connection:
        connection.execute(f'CREATE ROLE "{role}" LOGIN')
    control = Host(tmp_path / "control", database)
    shelf = Host(tmp_path / "shelf", database)
    for host in (control, shelf):
        host.folder.mkdir()
    control.migrate()
    added = control.manage("worker_host", "add", "shelf-1").stdout
    shelf.env["PRINTHOST_HOST_KEY"] = added.split("key (shown once): ")[1].split()[0]
    try:
        yield control, shelf, role
    finally:
        with psycopg.connect(database, autocommit=True) as connection:
            connection.execute(f'DROP OWNED BY "{role}"')
        with psycopg.connect(ADMIN, autocommit=True) as connection:
            connection.execute(f'DROP ROLE "{role}"')


def _grant(control: Host, role: str, host: str = "shelf-1") -> None:
    import psycopg

    sql = control.manage("worker_host", "grants", role, host).stdout
    with psycopg.connect(control.database_url, autocommit=True) as connection:
        for statement in sql.splitlines():
            connection.execute(statement)


def test_a_worker_host_prints_on_its_own_role_which_can_do_nothing_else(farm, tmp_path):
    import psycopg

    control, shelf, role = farm
    record = shelf.add_simulated_printer(
        "p1", sim_args="--time-scale 0", temperature_interval=1
    )
    shelf.shell(
        "from printers.models import Printer; from printers.hosts import WorkerHost; "
        "Printer.objects.filter(slug='p1').update("
        "worker_host=WorkerHost.objects.get(name='shelf-1'))"
    )
    text = segments(3000)
    source = tmp_path / "part.gcode"
    source.write_text(text)
    control.manage("add_job", "p1", str(source))
    _another_host_with_work(control, tmp_path)
    _grant(control, role)
    shelf.env["DATABASE_URL"] = _as_role(control.database_url, role)
    port = str(free_port())
    metrics = ("--metrics-port", port)
    # Its role may not check an admin's key: a scrape needs the token.
    refused = shelf.manage("runhost", "--no-web", "--worker-host", "shelf-1", *metrics, check=False)  # fmt: skip
    assert refused.returncode != 0
    assert "set PRINTHOST_METRICS_TOKEN" in refused.stderr
    shelf.env["PRINTHOST_METRICS_TOKEN"] = "role-test-token"

    with control.running("--no-workers"):
        shelf.env["PRINTHOST_CONTROL_URL"] = control.url
        with shelf.running("--worker-host", "shelf-1", *metrics, web=False) as runhost:
            # An upgrade's grants again while the host works (one transaction).
            _grant(control, role)
            state = lambda: control.query(
                f"SELECT state, message FROM jobs_job WHERE {P1}"
            )[0]
            wait_for(lambda: state()[0] == "completed", 90, "the job to complete")
            host = control.query(
                "SELECT instance, printers, version FROM printers_workerhost "
                "WHERE name = 'shelf-1'"
            )[0]
            assert str(runhost.pid) in host[0] and host[2]
            assert '"p1"' in str(host[1]).replace("'", '"')
            sampled = "SELECT count(*) FROM printers_temperaturesample"
            wait_for(lambda: control.query(sampled)[0][0] > 0, 30, "a sample")
            scrape = lambda: httpx.get(
                f"http://127.0.0.1:{port}/metrics",
                headers={"Authorization": "Bearer role-test-token"},
                timeout=10,
            )
            wait_for(lambda: _answers(scrape), 30, "the host's metrics")
            states = [
                dict(labels) for name, labels in samples(scrape().text)
                if name == "printhost_printer_state"
            ]  # fmt: skip
            assert {s["printer"] for s in states} == {"p1"}
        assert "lacks" not in shelf.log_tail(200)
        shelf_1 = "SELECT instance FROM printers_workerhost WHERE name = 'shelf-1'"
        assert control.query(shelf_1) == [("",)]

    ran = [
        c for c in record.read_text().splitlines() if not c.startswith(HOST_COMMANDS)
    ]
    assert ran == commands_of(text)
    sha = control.query(f"SELECT sha256 FROM jobs_job WHERE {P1}")[0][0]
    assert (shelf.folder / "cache" / "jobs" / sha).read_text() == text
    assert not (shelf.folder / "jobs").exists()  # no job storage on the host
    assert "worker:p1" not in control.log_tail(200)  # the control plane drove none
    assert "fetches job" in control.log_tail(200)
    assert control.query("SELECT outcome FROM jobs_historyentry") == [("completed",)]
    assert control.query("SELECT count(*) FROM printers_responseline")[0][0] > 0

    refused = (
        "SELECT password FROM auth_user",
        "SELECT key_hash FROM printhost_apikey",
        "SELECT * FROM django_session",
        "UPDATE printers_printer SET simulator = 'x'",
        "UPDATE printers_workerhost SET key_hash = ''",
        "UPDATE jobs_job SET file = 'other.gcode'",
        "INSERT INTO printers_queuedcommand (printer_id, text, state, origin) "
        "SELECT id, 'M104 S300', 'pending', 'x' FROM printers_printer",
        "INSERT INTO printhost_printerrole (user_id, role) VALUES (1, 40)",
        "INSERT INTO jobs_fileanalysis (sha256, state) VALUES ('x', 'done')",
    )
    control.query(  # p1's own command, for the updates' counterpart below
        "INSERT INTO printers_queuedcommand (printer_id, kind, text, origin, state, "
        "reply, created_at) SELECT id, 'command', 'M105', '', 'pending', '', now() "
        "FROM printers_printer WHERE slug = 'p1' RETURNING id"
    )
    with psycopg.connect(shelf.env["DATABASE_URL"], autocommit=True) as connection:
        for sql in refused + FORGED:
            with pytest.raises(psycopg.errors.InsufficientPrivilege):
                connection.execute(sql)
        # Another host's rows are out of its reach: its updates find none of them.
        for sql in UPDATES_OF_P2:
            assert connection.execute(sql).rowcount == 0, sql
            assert (
                connection.execute(
                    sql.replace("p2", "p1").replace("shelf-2", "shelf-1")
                ).rowcount
                == 1
            ), sql
        # What it does add: an SD print on its own printer (no stored file).
        sd_print = COPY_OF_P1_JOB.format(id=900002, extra=", 'file', ''", slug="p1")
        assert connection.execute(sd_print).rowcount == 1
    assert control.query(f"SELECT state FROM jobs_job WHERE {P2}") == [("queued",)]
    assert control.query(f"SELECT state FROM printers_queuedcommand WHERE {P2}") == [
        ("pending",)
    ]
    assert control.query(
        "SELECT lease_owner, state FROM printers_printer WHERE slug = 'p2'"
    ) == [("", "offline")]


P1 = "printer_id = (SELECT id FROM printers_printer WHERE slug = 'p1')"
P2 = "printer_id = (SELECT id FROM printers_printer WHERE slug = 'p2')"
#: What a taken-over shelf-1 would do to shelf-2's printer: each finds no row.
UPDATES_OF_P2 = (
    f"UPDATE jobs_job SET state = 'cancelled' WHERE {P2}",
    f"UPDATE printers_queuedcommand SET state = 'done' WHERE {P2}",
    "UPDATE printers_printer SET lease_owner = 'x', state = 'ready' WHERE slug = 'p2'",
    "UPDATE printers_workerhost SET hostname = 'x' WHERE name = 'shelf-2'",
)
#: A copy of p1's finished job, queued on the printer named and changed by *extra*.
COPY_OF_P1_JOB = (
    "INSERT INTO jobs_job SELECT (jsonb_populate_record(NULL::jobs_job, to_jsonb(j) "
    "|| jsonb_build_object('id', {id}, 'printer_id', p.id, 'state', 'queued'{extra}"
    f"))).* FROM jobs_job j, printers_printer p WHERE j.{P1} AND p.slug = '{{slug}}'"
)
#: ... and rows it would write for it: each breaks the row-level policy.
FORGED = (
    "INSERT INTO printers_responseline (printer_id, seq, time, text, kind) "
    "SELECT id, 999999, now(), 'forged', 0 FROM printers_printer WHERE slug = 'p2'",
    "INSERT INTO printers_temperaturesample (printer_id, time, temperatures) "
    "SELECT id, now(), '{}' FROM printers_printer WHERE slug = 'p2'",
    # Queued on p2, it would start printing there.
    COPY_OF_P1_JOB.format(id=900000, extra="", slug="p2"),
    # Even on its own printer a job naming a stored file is refused: the control
    # plane would serve the host that file, any printer's.
    COPY_OF_P1_JOB.format(id=900001, extra="", slug="p1"),
)


def _another_host_with_work(control: Host, tmp_path: Path) -> None:
    """Worker host shelf-2 with printer p2, a job queued on it and a command."""
    control.manage("worker_host", "add", "shelf-2")
    other = tmp_path / "other.gcode"
    other.write_text("G28\n")
    control.shell(
        "from printers.models import Printer, QueuedCommand; "
        "from printers.hosts import WorkerHost; "
        "p = Printer.objects.create(name='P2', slug='p2', port='/dev/ttyUSB7', "
        "worker_host=WorkerHost.objects.get(name='shelf-2')); "
        "QueuedCommand.objects.create(printer=p, text='M105')"
    )
    control.manage("add_job", "p2", str(other))


def _answers(scrape) -> bool:
    try:
        return scrape().status_code == 200
    except httpx.TransportError:
        return False


def test_runhost_refuses_a_role_short_of_a_grant_and_names_it(farm):
    import psycopg

    control, shelf, role = farm
    _grant(control, role)
    with psycopg.connect(control.database_url, autocommit=True) as connection:
        connection.execute(f'REVOKE UPDATE ON printers_queuedcommand FROM "{role}"')
    shelf.env["DATABASE_URL"] = _as_role(control.database_url, role)
    result = shelf.manage(
        "runhost", "--no-web", "--worker-host", "shelf-1", check=False
    )
    assert result.returncode != 0
    assert f"the database role '{role}' lacks" in result.stderr
    assert "UPDATE (state) ON printers_queuedcommand" in result.stderr
    assert "worker_host grants" in result.stderr
    # Nothing was claimed: the host row was never written by the refused runhost.
    assert control.query("SELECT instance FROM printers_workerhost") == [("",)]


def test_grants_refuse_a_role_or_host_name_that_is_not_plain(tmp_path):
    host = Host(tmp_path)
    result = host.manage("worker_host", "grants", 'x"; DROP TABLE', "shelf-1", check=False)  # fmt: skip
    assert result.returncode != 0
    assert "is not a plain role name" in result.stderr
    result = host.manage("worker_host", "grants", "ph_host", "a') OR (true", check=False)  # fmt: skip
    assert result.returncode != 0
    assert "is not a worker host's name" in result.stderr


def test_runhost_refuses_a_role_not_kept_to_its_own_hosts_rows(farm):
    import psycopg

    control, shelf, role = farm
    shelf.env["DATABASE_URL"] = _as_role(control.database_url, role)
    unknown = control.manage("worker_host", "grants", role, "shelf-9", check=False)
    assert unknown.returncode != 0
    assert "no worker host named shelf-9 (known: shelf-1)" in unknown.stderr
    start = ("runhost", "--no-web", "--worker-host", "shelf-1")

    control.manage("worker_host", "add", "shelf-2")
    _grant(control, role, "shelf-2")
    result = shelf.manage(*start, check=False)
    assert result.returncode != 0
    assert f"the database role '{role}' serves other worker hosts than shelf-1" in (
        result.stderr
    )
    assert f"worker_host grants {role} shelf-1" in result.stderr

    # Grants from before the policies: every privilege, no row kept from it.
    _grant(control, role)
    with psycopg.connect(control.database_url, autocommit=True) as connection:
        connection.execute("ALTER TABLE jobs_job DISABLE ROW LEVEL SECURITY")
    result = shelf.manage(*start, check=False)
    assert result.returncode != 0
    assert f"the database role '{role}' may write other hosts' rows of jobs_job" in (
        result.stderr
    )
    assert control.query("SELECT instance FROM printers_workerhost") == [("",), ("",)]

    # A control plane on a role the policies hold would see no printer or job.
    result = shelf.manage("runhost", "--no-workers", "--no-celery", check=False)
    assert result.returncode != 0
    assert f"the database role '{role}' is held to worker hosts' rows" in result.stderr


def test_runhost_on_a_database_older_than_its_code_says_migrate_first(farm):
    import psycopg

    control, shelf, _ = farm
    with psycopg.connect(control.database_url, autocommit=True) as connection:
        connection.execute("ALTER TABLE printers_printer DROP COLUMN link_stats")
    result = shelf.manage(
        "runhost", "--no-web", "--worker-host", "shelf-1", check=False
    )
    assert result.returncode != 0
    assert "link_stats" in result.stderr
    assert "run manage.py migrate on the control plane" in result.stderr


#: A worker's log on the host's role: its printer's lease taken, a batch stored.
LOG_AS_HOST = """
import json
from printers.models import Printer
from printers.protocol.events import LineKind
from printers.worker.lease import Lease
from printers.worker.responselog import ResponseLog
printer = Printer.objects.get(slug="p1")
lease = Lease(printer.pk, "a:1:x", 10, host="shelf-1")
lease.take(now=0.0)
log = ResponseLog(printer.pk, lease=lease)
for text in json.loads({texts!r}):
    log.add(text, LineKind.RESPONSE)
log.flush()
"""


def test_the_response_log_goes_in_line_for_line_under_the_row_policies(farm):
    control, shelf, role = farm
    control.shell(
        "from printers.models import Printer; from printers.hosts import WorkerHost; "
        "Printer.objects.create(name='P1', slug='p1', port='/dev/ttyUSB0', "
        "worker_host=WorkerHost.objects.get(name='shelf-1'))"
    )
    _grant(control, role)
    shelf.env["DATABASE_URL"] = _as_role(control.database_url, role)

    shelf.shell(LOG_AS_HOST.format(texts=json.dumps(AWKWARD)))

    rows = control.query(
        "SELECT seq, text, kind FROM printers_responseline ORDER BY seq"
    )
    assert rows == [(i + 1, text, 4) for i, text in enumerate(AWKWARD)]
    times = control.query("SELECT DISTINCT time FROM printers_responseline")
    assert len(times) == 1


def test_a_host_whose_grants_stop_covering_it_stops_and_says_why(farm):
    control, shelf, role = farm
    control.manage("worker_host", "add", "shelf-2")
    _grant(control, role)
    shelf.env["DATABASE_URL"] = _as_role(control.database_url, role)
    shelf.env["PRINTHOST_HEARTBEAT_SECONDS"] = "0.5"
    shelf.env["PRINTHOST_CONTROL_URL"] = "http://127.0.0.1:9"  # no file to fetch
    ours = "SELECT instance FROM printers_workerhost WHERE name = 'shelf-1'"
    with shelf.running("--worker-host", "shelf-1", web=False) as runhost:
        wait_for(lambda: control.query(ours)[0][0] != "", 30, "the host's claim")
        _grant(control, role, "shelf-2")  # an operator's slip: the wrong host
        wait_for(lambda: runhost.poll() is not None, 30, "the host to stop")
    assert "its database role may no longer write its row" in shelf.log_tail(40)
    assert "claimed by another runhost" not in shelf.log_tail(40)
