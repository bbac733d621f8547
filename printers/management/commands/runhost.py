"""`manage.py runhost`: daphne plus one worker (and simulator) per enabled printer.

A print farm splits it: the control plane (`--no-workers`: daphne, Celery) and one
worker host per computer the printers are plugged into (`--no-web --worker-host
NAME`: that host's printers' workers, simulators and file fetcher).
"""

from __future__ import annotations

import os
import signal
from typing import TYPE_CHECKING, Any

from django.conf import settings
from django.core.management.base import BaseCommand, CommandError
from django.db import ProgrammingError, connection

from printers.heartbeat import HostRefused, HostRegistration
from printers.host_role import (
    confinement_problem,
    control_plane_problem,
    missing_privileges,
)
from printers.supervisor import Supervisor
from printhost.metrics_access import bind_refusal, key_check_refusal
from printhost.startup import secret_key_refusal

if TYPE_CHECKING:
    from argparse import ArgumentParser
    from types import FrameType


class Command(BaseCommand):
    help = (
        "Serve the web UI/API and run one worker per enabled printer, restarting them."
    )

    def add_arguments(self, parser: ArgumentParser) -> None:
        parser.add_argument("--bind", default="127.0.0.1")
        parser.add_argument("--port", type=int, default=8000)
        parser.add_argument("--no-web", action="store_true", help="workers only")
        parser.add_argument(
            "--no-celery",
            action="store_true",
            help="no Celery worker or beat here (another host runs them)",
        )
        parser.add_argument(
            "--no-workers",
            action="store_true",
            help="the control plane of a farm: no printer workers or simulators here",
        )
        parser.add_argument(
            "--worker-host",
            metavar="NAME",
            default="",
            help="run the printers assigned to worker host NAME only, with its "
            "heartbeat and file fetcher; implies --no-celery (requires --no-web)",
        )
        parser.add_argument(
            "--metrics-port",
            type=int,
            default=0,
            help="a worker host serves its own Prometheus /metrics on this port "
            "(0 = none; the control plane serves /metrics with the web UI)",
        )
        parser.add_argument("--metrics-bind", default="127.0.0.1")

    def handle(self, *args: Any, **options: Any) -> None:
        if options["metrics_port"]:
            if refusal := bind_refusal(options["metrics_bind"]):
                raise CommandError(f"--metrics-bind: {refusal}")
            if refusal := key_check_refusal():
                raise CommandError(f"--metrics-port: {refusal}")
        # Children (simulators: their --record check) see the same data directory.
        os.environ["PRINTHOST_DATA_DIR"] = str(settings.DATA_DIR)
        worker_host = self._worker_host(options)
        if worker_host is None and (problem := control_plane_problem(connection)):
            raise CommandError(problem)
        # Workers claim only printers of the host they run on (their lease says so).
        os.environ["PRINTHOST_WORKER_HOST"] = worker_host.name if worker_host else ""
        if not options["no_web"]:
            refusal = secret_key_refusal(
                secret_key=settings.SECRET_KEY,
                debug=settings.DEBUG,
                hosts=[options["bind"]],
            )
            if refusal:
                raise CommandError(refusal)
        self.supervisor = Supervisor(
            bind=options["bind"],
            port=options["port"],
            serve_web=not options["no_web"],
            celery=not options["no_celery"] and worker_host is None,
            workers=not options["no_workers"],
            worker_host=worker_host,
            metrics_bind=options["metrics_bind"],
            metrics_port=options["metrics_port"],
        )
        signal.signal(signal.SIGTERM, self.on_signal)
        signal.signal(signal.SIGINT, self.on_signal)
        if not options["no_web"]:
            self.stdout.write(
                f"printhost on http://{options['bind']}:{options['port']}/"
            )
        self.supervisor.run()
        self.stdout.write("printhost stopped")

    def _worker_host(self, options: dict[str, Any]) -> HostRegistration | None:
        """This runhost as the worker host it names, claimed; None on a control plane."""
        name = options["worker_host"]
        if not name:
            return None
        if not options["no_web"]:
            raise CommandError(
                "a worker host serves no web UI: run it with --no-web --worker-host "
                f"{name} (the control plane serves the UI and the API)"
            )
        if options["no_workers"]:
            raise CommandError("--worker-host runs workers: drop --no-workers")
        try:
            missing = missing_privileges(connection)
        except ProgrammingError as error:  # a table or column this code writes
            raise CommandError(
                f"the database's tables are not this code's ({error}): run "
                "manage.py migrate on the control plane before upgrading its hosts"
            ) from None
        if missing:
            role = connection.settings_dict["USER"]
            raise CommandError(
                f"the database role {role!r} lacks what a worker host needs: "
                f"{'; '.join(missing)}. As the database's owner, run the SQL of "
                f"`manage.py worker_host grants {role} {name}` (again after each "
                "migrate)"
            )
        if problem := confinement_problem(connection, name):
            raise CommandError(problem)
        registration = HostRegistration(name)
        try:
            host = registration.claim()
        except HostRefused as error:
            raise CommandError(str(error)) from None
        slugs = ", ".join(host.printer_set.values_list("slug", flat=True)) or "none yet"
        self.stdout.write(f"worker host {name}: printers {slugs}")
        return registration

    def on_signal(self, signum: int, frame: FrameType | None) -> None:
        self.supervisor.shutdown = True
