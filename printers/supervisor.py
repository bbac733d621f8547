"""runhost's supervisor: daphne, Celery (worker and beat), the simulators and one
worker per enabled printer.

Which printers: a worker host (`--worker-host NAME`) runs the workers and
simulators of the printers assigned to it, and its fetcher; the control plane
(`--no-workers`) runs none; a one-computer runhost runs the printers assigned to
no worker host. The database may be away for a while (a restart): the
supervisor keeps what runs running and retries, it never stops a worker for it.

One loop, no threads: start what should run, poll children, restart the ones that
died with a doubling delay, and on stop send SIGTERM then wait (SIGKILL after a
grace period).
"""

from __future__ import annotations

import contextlib
import logging
import os
import shlex
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

from django.conf import settings
from django.db import DatabaseError

from printers.models import Printer
from printers.reaper import reap_silent_workers
from printhost.longrunning import close_failed_connections

if TYPE_CHECKING:
    from collections.abc import Callable

    from printers.heartbeat import HostRegistration

logger = logging.getLogger("printhost.runhost")
T = TypeVar("T")

MANAGE = str(Path(__file__).resolve().parent.parent / "manage.py")
#: Restart delays (s) for a child that died; reset once it ran this long.
RESTART_FIRST = 1.0
RESTART_CAP = 60.0
HEALTHY_AFTER = 30.0
STOP_GRACE = 10.0
RESCAN_SECONDS = 5.0
#: How long daphne lets a websocket handshake take (s).
WEBSOCKET_CONNECT_SECONDS = 30
#: How often the control plane looks for workers whose lease ran out (s).
REAP_SECONDS = 1.0
#: Printing comes first: on a busy small computer the printer workers and their
#: simulators keep the default priority, and everything that can wait runs "nicer"
#: (a web page, a file analysis, a download wait; a printer's planner must not run
#: dry). Children not named here keep the default.
NICENESS = {
    "daphne": 5,
    "terminal": 5,
    "dispatcher": 5,
    "celery": 10,
    "celery-beat": 10,
    "fetcher": 10,
    "metrics": 10,
}


#: The children that serve pages (settings.WEB_APPS).
SERVES_PAGES = frozenset({"daphne"})


@dataclass
class Child:
    """One supervised process and its restart bookkeeping."""

    name: str
    argv: list[str]
    process: subprocess.Popen[bytes] | None = None
    started_at: float = 0.0
    delay: float = RESTART_FIRST
    restart_at: float = 0.0
    restarts: int = 0
    tags: set[str] = field(default_factory=set)

    def start(self, now: float) -> None:
        logger.info("starting %s: %s", self.name, shlex.join(self.argv))
        self.process = subprocess.Popen(self.argv, env=child_environment(self.name))
        self.started_at = now
        nice = NICENESS.get(self.name, 0)
        if nice:
            # Before the child forks its own (Celery's pool inherits it).
            with contextlib.suppress(OSError):
                mine = os.getpriority(os.PRIO_PROCESS, 0)
                os.setpriority(os.PRIO_PROCESS, self.process.pid, min(19, mine + nice))

    def poll(self, now: float) -> None:
        """Notice a death and schedule the restart with backoff."""
        if self.process is None or self.process.poll() is None:
            return
        code = self.process.returncode
        self.process = None
        if now - self.started_at >= HEALTHY_AFTER:
            self.delay = RESTART_FIRST
        self.restart_at = now + self.delay
        logger.warning(
            "%s exited with code %s; restarting in %.1f s", self.name, code, self.delay
        )
        self.delay = min(self.delay * 2, RESTART_CAP)
        self.restarts += 1

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def terminate(self) -> None:
        if self.running:
            self.process.send_signal(signal.SIGTERM)

    def wait(self, until: float) -> None:
        if self.process is None:
            return
        try:
            self.process.wait(timeout=max(0.0, until - time.monotonic()))
        except subprocess.TimeoutExpired:
            logger.warning("%s did not stop in time; killing it", self.name)
            self.process.kill()
            self.process.wait()


def child_environment(name: str) -> dict[str, str]:
    """The environment of the child *name*: runhost's own, with PRINTHOST_WEB_APPS
    set for it (settings.WEB_APPS): 1 for the web server, 0 for every other child,
    which then loads neither daphne nor the API docs' app."""
    return {**os.environ, "PRINTHOST_WEB_APPS": "1" if name in SERVES_PAGES else "0"}


def celery_children(python: str) -> dict[str, list[str]]:
    """The Celery worker (file analysis) and beat (periodic upkeep) of this host."""
    app = [python, "-m", "celery", "--app", "printhost"]
    return {
        "celery": [
            *app, "worker", "--loglevel", "INFO",
            "--concurrency", str(settings.PRINTHOST_CELERY_CONCURRENCY),
            "--hostname", f"printhost@{socket.gethostname()}",
            "--max-tasks-per-child", "100",
            "--without-gossip", "--without-mingle",
        ],
        "celery-beat": [
            *app, "beat", "--loglevel", "INFO",
            "--schedule", settings.CELERY_BEAT_SCHEDULE_FILENAME,
        ],
    }  # fmt: skip


def _farm_in_use() -> bool:
    """The dispatcher runs once the farm queue was used (a process less otherwise)."""
    from jobs.farm.models import FarmJob

    return FarmJob.objects.exists()


class Supervisor:
    """Keeps the host's processes running until `shutdown` is set."""

    def __init__(
        self,
        *,
        bind: str,
        port: int,
        serve_web: bool = True,
        celery: bool = True,
        workers: bool = True,
        worker_host: HostRegistration | None = None,
        metrics_bind: str = "127.0.0.1",
        metrics_port: int = 0,
    ) -> None:
        self.bind = bind
        self.port = port
        self.serve_web = serve_web
        self.celery = celery
        self.workers = workers
        self.worker_host = worker_host
        self.metrics_bind = metrics_bind
        self.metrics_port = metrics_port
        self.children: dict[str, Child] = {}
        self.shutdown = False
        self._rescan_at = 0.0
        self._beat_at = 0.0
        self._reap_at = 0.0
        #: The control plane (not a worker host) marks silent workers' printers.
        self.reaps = worker_host is None
        self._database_away = False

    def run(self) -> None:
        try:
            while not self.shutdown:
                self.step(time.monotonic())
                time.sleep(0.2)
        finally:
            self.stop()

    def step(self, now: float) -> None:
        """Reconcile wanted children with running ones; restart the dead when due."""
        if now >= self._rescan_at:
            self._rescan_at = now + RESCAN_SECONDS
            wanted = self._from_database(self.wanted)
            if wanted is not None:
                self._reconcile(wanted, now)
        if self.reaps and now >= self._reap_at:
            self._reap_at = now + REAP_SECONDS
            self._from_database(reap_silent_workers)
        if self.worker_host is not None and now >= self._beat_at:
            self._beat_at = now + settings.PRINTHOST_HEARTBEAT_SECONDS
            still_ours = self._from_database(self._beat)
            if still_ours is False:
                reason = self._from_database(self.worker_host.lost_reason)
                logger.error("%s: stopping this runhost", reason or "heartbeat refused")
                self.shutdown = True
                return
        for child in self.children.values():
            child.poll(now)
            if child.process is None and now >= child.restart_at:
                child.start(now)

    def _from_database(self, read: Callable[[], T]) -> T | None:
        """*read*'s answer, or None while the database is away (logged once)."""
        try:
            close_failed_connections()
            answer = read()
        except DatabaseError as error:
            if not self._database_away:
                logger.warning("database unavailable (%s); workers keep running", error)
            self._database_away = True
            return None
        if self._database_away:
            logger.info("database reachable again")
        self._database_away = False
        return answer

    def _beat(self) -> bool:
        assert self.worker_host is not None
        printers = {
            name.removeprefix("worker:"): {
                "pid": child.process.pid if child.process else None,
                "running": child.running,
                "restarts": child.restarts,
            }
            for name, child in self.children.items()
            if name.startswith("worker:")
        }
        return self.worker_host.beat(printers)

    def printers(self) -> list[Printer]:
        """The enabled printers this runhost drives."""
        if not self.workers:
            return []
        printers = Printer.objects.filter(enabled=True)
        if self.worker_host is not None:
            printers = printers.filter(worker_host__name=self.worker_host.name)
        else:
            printers = printers.filter(worker_host__isnull=True)
        return list(printers.order_by("pk"))

    def wanted(self) -> dict[str, list[str]]:
        """What should run now: web server, simulators, terminals, then workers."""
        python = sys.executable
        wanted: dict[str, list[str]] = {}
        if self.serve_web:
            # Behind a reverse proxy (PRINTHOST_BEHIND_PROXY) a client's address is
            # the proxy's X-Forwarded-For: login throttling counts per address.
            proxied = getattr(settings, "SECURE_PROXY_SSL_HEADER", None)
            wanted["daphne"] = [
                python, "-m", "printhost.serve", "-b", self.bind, "-p", str(self.port),
                # A websocket's handshake reads its caller from the database: with
                # many clients connecting at once on a busy small computer that
                # takes longer than daphne's 5 s, which closes it unanswered.
                "--websocket_connect_timeout", str(WEBSOCKET_CONNECT_SECONDS),
                *(["--proxy-headers"] if proxied else []),
                "printhost.asgi:application",
            ]  # fmt: skip
        if self.celery:
            wanted.update(celery_children(python))
        printers = self.printers()
        for printer in printers:
            if printer.simulator:
                argv = shlex.split(printer.simulator)
                wanted[f"sim:{printer.slug}"] = [
                    python,
                    "-m",
                    "printers.simulator",
                    *argv,
                ]
        if (
            self.worker_host is None
            and Printer.objects.filter(
                enabled=True, terminal_port__isnull=False
            ).exists()
        ):
            wanted["terminal"] = [python, MANAGE, "run_terminal"]
        if self.reaps and _farm_in_use():
            wanted["dispatcher"] = [python, MANAGE, "run_dispatcher"]
        if self.worker_host is not None and self.metrics_port:
            wanted["metrics"] = [
                python, MANAGE, "serve_metrics", "--worker-host", self.worker_host.name,
                "--bind", self.metrics_bind, "--port", str(self.metrics_port),
            ]  # fmt: skip
        if self.worker_host is not None and settings.PRINTHOST_CONTROL_URL:
            wanted["fetcher"] = [
                python, MANAGE, "fetch_files", "--worker-host", self.worker_host.name,
            ]  # fmt: skip
        for printer in printers:
            wanted[f"worker:{printer.slug}"] = [
                python,
                MANAGE,
                "run_printer",
                printer.slug,
            ]
        return wanted

    def _reconcile(self, wanted: dict[str, list[str]], now: float) -> None:
        for name in list(self.children):
            if name not in wanted or self.children[name].argv != wanted.get(name):
                child = self.children.pop(name)
                child.terminate()
                child.wait(time.monotonic() + STOP_GRACE)
        for name, argv in wanted.items():
            if name not in self.children:
                self.children[name] = Child(name, argv, restart_at=now)

    def stop(self) -> None:
        """Workers first (they save progress and release their printers), then the rest.

        Each group gets SIGTERM and a grace period; what is still alive is killed.
        """
        workers = [c for c in self.children.values() if c.name.startswith("worker:")]
        others = [c for c in self.children.values() if c not in workers]
        for group in (workers, others):
            for child in group:
                child.terminate()
            until = time.monotonic() + STOP_GRACE
            for child in group:
                child.wait(until)
        self.children.clear()
        if self.worker_host is not None:
            self._from_database(self.worker_host.leave)
