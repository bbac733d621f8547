"""A whole print farm on this machine: PostgreSQL, Redis, one control plane and N
worker hosts, each a `runhost` in its own process group with its own data
directory; P simulated printers (their firmware simulators started here, one per
printer, linked inside their host's data directory); J jobs uploaded to the farm.

The simulators stand for the printers' own boards: they run apart from the worker
hosts, as a printer with its own power supply goes on when the computer it is
plugged into dies, so killing a host leaves their records whole.

The harness acts as an operator would, through the API: it uploads to the farm
(`/printer/job/farm?a=upload&material=...`) and confirms each bed clear
(`/printer/bedclear/<slug>`) once a printer waits for it (farm printers keep
`auto_start` off). It reads the database directly to watch (never to act).
"""

from __future__ import annotations

import json
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import urlparse

import httpx

from printers.simulator.process import SimulatorProcess, start_simulator
from tests.conftest import wait_for
from tests.farmrig.fleet import JobSpec, PrinterSpec, fleet, job_mix
from tests.farmrig.processes import Runhost
from tests.hosts import Host, _accepts, free_port, postgres_url, redis_url
from tests.netfault import TcpProxy

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable

#: Job states a run ends in.
FINAL = ("completed", "aborted", "failed", "interrupted")
#: A PostgreSQL server without autovacuum (this machine's): the harness vacuums and
#: analyses the tables every farm updates row by row this often (s), as autovacuum
#: does in a default installation (docs/deploy.md), so the plans the bench
#: measures are production's and not those of tables never analysed, thick with
#: dead rows (the printers table: 12 live rows, 24,864 dead ones).
VACUUM_SECONDS = 30.0
#: What autovacuum would keep lean here: the tables updated several times a second.
HOT_TABLES = (
    "printers_printer", "jobs_job", "jobs_farmjob", "printers_queuedcommand",
    "printers_workerhost", "printhost_apikey",
)  # fmt: skip


@dataclass
class FarmConfig:
    """The farm's size and speed."""

    hosts: int = 3
    printers: int = 6
    jobs: int = 10
    #: The simulators' motion timing: moves take the firmware's time times this.
    time_scale: float = 0.05
    #: The simulators' heat-ups and homing take no time (`--instant-waits`).
    instant_waits: bool = False
    baud: int = 250000
    lease_seconds: float = 3.0
    #: Every third job prints one of the long real files (the full-size farm).
    long_files: bool = False
    #: Jobs ask for materials, nozzles, profiles, tags, volumes (`fleet.job_mix`).
    mixed: bool = True
    #: Every process reaches PostgreSQL / Redis through a proxy a test can cut.
    proxy_postgres: bool = False
    proxy_redis: bool = False
    redis_db: int = 6
    #: Every wait of the harness's own lasts this many times longer (a big farm).
    patience: float = 1.0
    #: More settings for every runhost (PRINTHOST_*).
    env: dict[str, str] = field(default_factory=dict)


class Farm:
    """The farm's parts, set up by `setup()`, run by `start()`, ended by `close()`."""

    def __init__(self, root: Path, config: FarmConfig) -> None:
        self.root = root
        self.config = config
        self.printers: list[PrinterSpec] = fleet(config.printers, config.hosts)
        self.jobs: list[JobSpec] = job_mix(
            config.jobs, self.printers, long=config.long_files, mixed=config.mixed
        )
        self.host_names = [f"shelf-{k + 1}" for k in range(config.hosts)]
        self.sims: dict[str, SimulatorProcess] = {}
        self.runhosts: dict[str, Runhost] = {}
        self.keys: dict[str, str] = {}
        self.postgres_proxy: TcpProxy | None = None
        self.redis_proxy: TcpProxy | None = None
        self.database = ""
        self.operator = ""
        self.ids: dict[str, int] = {}
        self.uploaded: dict[int, JobSpec] = {}
        self.cleared: dict[str, float] = {}
        #: Slugs whose bed the harness leaves alone (a test looks at them).
        self.hold_beds: set[str] = set()
        #: Jobs queued outside the farm (a benchmark's baseline) and the records'
        #: lines they left: the checks leave both out.
        self.other_jobs: set[int] = set()
        self.record_offsets: dict[str, int] = {}
        #: Every lease owner seen on each printer while tending, in order.
        self.owners: dict[str, list[str]] = {}
        self._db: Any = None
        self._vacuum_at = 0.0
        #: Whether the server runs autovacuum (None: not asked yet).
        self._autovacuum: bool | None = None

    # -- set-up --------------------------------------------------------------------

    def setup(self) -> None:
        """A fresh database and Redis space, the hosts, printers, operator, simulators."""
        self.database = postgres_url()
        redis = redis_url(self.config.redis_db)
        database, redis = self._through_proxies(self.database, redis)
        tag = uuid.uuid4().hex[:8]
        common = {
            "PRINTHOST_CHANNEL_PREFIX": f"farmtest-{tag}",
            "PRINTHOST_CELERY_QUEUE": f"farmtest-{tag}",
            "PRINTHOST_LEASE_SECONDS": str(self.config.lease_seconds),
            **self.config.env,
        }
        self.control = Host(self.root / "control", database, redis)
        self.shelves = {
            name: Host(self.root / name, database, redis) for name in self.host_names
        }
        for host in (self.control, *self.shelves.values()):
            host.folder.mkdir(parents=True)
            host.env.update(common)
        # Set-up and checks go straight to PostgreSQL, never through a proxy.
        direct = Host(self.control.folder, self.database)
        direct.migrate()
        for slug, sim in self._start_simulators().items():
            self.sims[slug] = sim
        answer = direct.shell(self._setup_code())
        self.keys = json.loads(answer.splitlines()[-1])
        self.ids = self.keys.pop("ids")
        self.operator = direct.add_user("operator", "operator")

    def _through_proxies(self, database: str, redis: str) -> tuple[str, str]:
        if self.config.proxy_postgres:
            self.postgres_proxy = TcpProxy(("127.0.0.1", 5432))
            database = self.postgres_proxy.url(
                "postgresql", urlparse(database).path, user="postgres"
            )
        if self.config.proxy_redis:
            self.redis_proxy = TcpProxy(("127.0.0.1", 6379))
            redis = self.redis_proxy.url("redis", f"/{self.config.redis_db}")
        return database, redis

    def _start_simulators(self) -> dict[str, SimulatorProcess]:
        args = ["--baud", str(self.config.baud)]
        args += ["--time-scale", f"{self.config.time_scale:g}"]
        if self.config.instant_waits:
            args.append("--instant-waits")
        return {
            p.slug: start_simulator(
                self.shelves[p.host].folder, "marlin", *args, name=p.slug
            )
            for p in self.printers
        }

    def _setup_code(self) -> str:
        rows = [
            {
                "slug": p.slug, "name": p.slug.upper(), "host": p.host,
                "port": str(self.sims[p.slug].link), "baud": self.config.baud,
                # The checks read every line a run logged.
                "response_log_limit": 10**7, **p.fields(),
            }
            for p in self.printers
        ]  # fmt: skip
        return f"""
import json
from printers.hosts import WorkerHost
from printers.models import Printer
keys = {{}}
for name in {self.host_names!r}:
    host = WorkerHost.objects.create(name=name)
    keys[name] = host.issue_key()
ids = {{}}
for row in json.loads({json.dumps(json.dumps(rows))}):
    host = WorkerHost.objects.get(name=row.pop("host"))
    ids[row["slug"]] = Printer.objects.create(worker_host=host, firmware="marlin",
        **row).pk
keys["ids"] = ids
print(json.dumps(keys))
"""

    # -- running ------------------------------------------------------------------

    def start(self, ready_within: float = 90) -> None:
        """The control plane, then every worker host; returns once every printer
        is idle (connected, its worker holding its lease)."""
        self.control.port = free_port()
        control = Runhost(
            "control", ["--port", str(self.control.port), "--no-workers"],
            self.control.env, self.control.folder / "runhost.log",
        )  # fmt: skip
        self.runhosts["control"] = control
        control.start()
        # The hosts start meanwhile: their fetchers retry until it listens.
        for name in self.host_names:
            self.start_host(name)
        wait_for(
            lambda: _accepts(self.control.port) or not control.alive(),
            60, "the control plane to listen",
        )  # fmt: skip
        assert control.alive(), control.log_text()[-3000:]
        wait_for(
            lambda: self.printer_states() == {"idle"},
            ready_within * self.config.patience,
            "every printer to be idle", step=self._watch_hosts,
        )  # fmt: skip

    def start_host(self, name: str) -> None:
        host = self.shelves[name]
        host.env["PRINTHOST_CONTROL_URL"] = self.control.url
        host.env["PRINTHOST_HOST_KEY"] = self.keys[name]
        runhost = self.runhosts.get(name) or Runhost(
            name, ["--no-web", "--worker-host", name], host.env,
            host.folder / "runhost.log",
        )  # fmt: skip
        self.runhosts[name] = runhost
        runhost.start()

    def _watch_hosts(self) -> None:
        for runhost in self.runhosts.values():
            assert runhost.process is None or runhost.down or runhost.alive(), (
                f"{runhost.name} exited:\n{runhost.log_text()[-3000:]}"
            )
        time.sleep(0.1)

    def close(self) -> None:
        """Every runhost stopped (the worker hosts together, then the control
        plane), every simulator, the proxies."""
        for names in (self.host_names, ["control"]):
            stopping = [self.runhosts[n] for n in names if n in self.runhosts]
            for runhost in stopping:
                runhost.terminate()
            until = time.monotonic() + 60.0
            for runhost in stopping:
                runhost.finish(until)
        for sim in self.sims.values():
            sim.stop()
        for proxy in (self.postgres_proxy, self.redis_proxy):
            if proxy is not None:
                proxy.close()
        if self._db is not None:
            self._db.close()

    # -- acting as an operator ----------------------------------------------------

    def api(self) -> httpx.Client:
        return httpx.Client(
            base_url=self.control.url, headers={"X-Api-Key": self.operator},
            timeout=30,
        )  # fmt: skip

    def upload(self, jobs: Iterable[JobSpec] | None = None) -> None:
        """Upload *jobs* (all by default) to the farm queue, in order."""
        with self.api() as client:
            for job in self.jobs if jobs is None else jobs:
                response = client.post(
                    "/printer/job/farm", params={"a": "upload", **job.asks},
                    files={"filename": (job.name, job.text().encode())},
                )  # fmt: skip
                assert response.status_code == 200, response.text
                self.uploaded[response.json()["data"]["id"]] = job

    def upload_to(self, slug: str, job: JobSpec) -> int:
        """Queue *job* on one printer (not the farm); its job id."""
        with self.api() as client:
            response = client.post(
                f"/printer/job/{slug}", params={"a": "upload"},
                files={"filename": (job.name, job.text().encode())},
            )  # fmt: skip
        assert response.status_code == 200, response.text
        return response.json()["data"]["id"]

    def clear_beds(self, client: httpx.Client) -> None:
        """Confirm the bed clear on every printer waiting for it (once every 3 s at
        most per printer); a refusal (the database away: 5xx) is tried again."""
        now = time.monotonic()
        rows = self.query("SELECT slug, state, lease_owner FROM printers_printer")
        for slug, state, owner in rows:
            seen = self.owners.setdefault(slug, [])
            if owner and (not seen or seen[-1] != owner):
                seen.append(owner)
            if state != "waitstart" or slug in self.hold_beds:
                continue
            if now - self.cleared.get(slug, 0.0) < 3:
                continue
            try:
                response = client.post(f"/printer/bedclear/{slug}")
            except httpx.HTTPError:
                continue
            if response.status_code in (200, 409):
                self.cleared[slug] = now

    def tend(self, until: Callable[[], bool], timeout: float, what: str) -> None:
        """Clear beds as they need it until *until* holds (bounded by *timeout*)."""
        with self.api() as client:

            def step() -> None:
                self.clear_beds(client)
                self._watch_hosts()
                self.vacuum_if_due()

            wait_for(until, timeout * self.config.patience, what, step=step)

    def run_to_end(self, timeout: float) -> None:
        """Tend the farm until every uploaded job ran and no printer has work."""
        self.tend(self.all_done, timeout, "every farm job to run")

    def all_done(self) -> bool:
        farm = self.query("SELECT state FROM jobs_farmjob")
        if len(farm) < len(self.uploaded) or any(s != "assigned" for (s,) in farm):
            return False
        jobs = self.query("SELECT state FROM jobs_job")
        return len(jobs) >= len(farm) and all(s in FINAL for (s,) in jobs)

    def vacuum_if_due(self) -> None:
        """What autovacuum does, when the server runs without it (VACUUM_SECONDS)."""
        now = time.monotonic()
        if now < self._vacuum_at:
            return
        self._vacuum_at = now + VACUUM_SECONDS
        if self._autovacuum is None:
            self._autovacuum = self.query("SHOW autovacuum")[0][0] == "on"
        if self._autovacuum:
            return
        tables = {t for (t,) in self.query("SELECT tablename FROM pg_tables")}
        self.query("SELECT 1")  # the harness's own connection, open
        for table in HOT_TABLES:
            if table in tables:
                self._db.execute(f"VACUUM (ANALYZE) {table}")
        self._db.execute("ANALYZE")

    # -- watching -----------------------------------------------------------------

    def query(self, sql: str, *args: object) -> list[tuple]:
        """Rows from the farm's database (direct, never through a proxy)."""
        import psycopg

        if self._db is None or self._db.closed:
            self._db = psycopg.connect(self.database, autocommit=True)
        return self._db.execute(sql, args).fetchall()

    def printer_states(self) -> set[str]:
        return {s for (s,) in self.query("SELECT state FROM printers_printer")}

    def jobs_by_state(self) -> dict[str, int]:
        rows = self.query("SELECT state, COUNT(*) FROM jobs_job GROUP BY state")
        return dict(rows)

    def running(self) -> list[tuple[str, int, int]]:
        """(slug, lines acked, lines in the file) of every printing job."""
        return self.query(
            "SELECT p.slug, j.lines_acked, j.line_count FROM jobs_job j "
            "JOIN printers_printer p ON p.id = j.printer_id WHERE j.state = 'printing'"
        )

    def mid_print(self, slugs: Iterable[str], share: float, timeout: float) -> None:
        """Tend until each of *slugs* prints a job past *share* of its lines."""
        wanted = set(slugs)

        def under_way() -> bool:
            going = {s for s, acked, count in self.running() if acked >= share * count}
            return wanted <= going

        self.tend(under_way, timeout, f"{sorted(wanted)} to be mid-print")

    def lease_owners(self) -> dict[str, str]:
        return dict(self.query("SELECT slug, lease_owner FROM printers_printer"))

    def logs(self) -> str:
        return "\n".join(r.log_text() for r in self.runhosts.values())
