"""`manage.py runhost`: daphne plus one worker (and simulator) per enabled printer."""

from __future__ import annotations

import os
import signal
from typing import TYPE_CHECKING, Any

from django.conf import settings
from django.core.management.base import BaseCommand, CommandError

from printers.supervisor import Supervisor
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

    def handle(self, *args: Any, **options: Any) -> None:
        # Children (simulators: their --record check) see the same data directory.
        os.environ["PRINTHOST_DATA_DIR"] = str(settings.DATA_DIR)
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
            celery=not options["no_celery"],
        )
        signal.signal(signal.SIGTERM, self.on_signal)
        signal.signal(signal.SIGINT, self.on_signal)
        if not options["no_web"]:
            self.stdout.write(
                f"printhost on http://{options['bind']}:{options['port']}/"
            )
        self.supervisor.run()
        self.stdout.write("printhost stopped")

    def on_signal(self, signum: int, frame: FrameType | None) -> None:
        self.supervisor.shutdown = True
