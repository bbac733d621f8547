"""runhost's supervisor: daphne, Celery (worker and beat), the simulators and one
worker per enabled printer.

One loop, no threads: start what should run, poll children, restart the ones that
died with a doubling delay, and on stop send SIGTERM then wait (SIGKILL after a
grace period).
"""

from __future__ import annotations

import logging
import shlex
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from django.conf import settings

from printers.models import Printer

logger = logging.getLogger("printhost.runhost")

MANAGE = str(Path(__file__).resolve().parent.parent / "manage.py")
#: Restart delays (s) for a child that died; reset once it ran this long.
RESTART_FIRST = 1.0
RESTART_CAP = 60.0
HEALTHY_AFTER = 30.0
STOP_GRACE = 10.0
RESCAN_SECONDS = 5.0


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
        self.process = subprocess.Popen(self.argv)
        self.started_at = now

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


class Supervisor:
    """Keeps the host's processes running until `shutdown` is set."""

    def __init__(
        self, *, bind: str, port: int, serve_web: bool = True, celery: bool = True
    ) -> None:
        self.bind = bind
        self.port = port
        self.serve_web = serve_web
        self.celery = celery
        self.children: dict[str, Child] = {}
        self.shutdown = False
        self._rescan_at = 0.0

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
            self._reconcile(self.wanted(), now)
        for child in self.children.values():
            child.poll(now)
            if child.process is None and now >= child.restart_at:
                child.start(now)

    def wanted(self) -> dict[str, list[str]]:
        """What should run now: web server, simulators, terminals, then workers."""
        python = sys.executable
        wanted: dict[str, list[str]] = {}
        if self.serve_web:
            wanted["daphne"] = [
                python, "-m", "printhost.serve", "-b", self.bind, "-p", str(self.port),
                "printhost.asgi:application",
            ]  # fmt: skip
        if self.celery:
            wanted.update(celery_children(python))
        printers = list(Printer.objects.filter(enabled=True).order_by("pk"))
        for printer in printers:
            if printer.simulator:
                argv = shlex.split(printer.simulator)
                wanted[f"sim:{printer.slug}"] = [
                    python,
                    "-m",
                    "printers.simulator",
                    *argv,
                ]
        if any(printer.terminal_port for printer in printers):
            wanted["terminal"] = [python, MANAGE, "run_terminal"]
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
