"""`manage.py run_printer <slug>`: the long-running worker of one printer."""

from __future__ import annotations

import signal
from typing import TYPE_CHECKING, Any

from django.core.management.base import BaseCommand, CommandError

from printers.models import Printer
from printers.worker.lease import LeaseLost
from printers.worker.loop import PrinterWorker
from printers.worker.portlock import PortBusy, PortLock

if TYPE_CHECKING:
    from argparse import ArgumentParser
    from types import FrameType


class Command(BaseCommand):
    help = "Drive one printer: stream its jobs, answer its clients, log its responses."

    def add_arguments(self, parser: ArgumentParser) -> None:
        parser.add_argument("slug", help="the printer's slug")

    def handle(self, *args: Any, **options: Any) -> None:
        slug = options["slug"]
        try:
            printer = Printer.objects.get(slug=slug)
        except Printer.DoesNotExist:
            known = ", ".join(Printer.objects.values_list("slug", flat=True)) or "none"
            raise CommandError(f"unknown printer {slug!r} (known: {known})") from None
        # The port first: a second worker for it must stop before it claims the
        # lease or settles what the first left (printers/worker/portlock.py).
        port = PortLock(printer.port)
        try:
            port.acquire()
        except PortBusy as error:
            raise CommandError(f"printer {slug}: {error}") from None
        self.worker = PrinterWorker(printer, alone=True)
        # Holding the port, the worker may drive on while the database is away.
        self.worker.lease.keep_while_away = True
        signal.signal(signal.SIGTERM, self.on_signal)
        signal.signal(signal.SIGINT, self.on_signal)
        try:
            self.worker.run()
        except LeaseLost as error:
            raise CommandError(str(error)) from None
        finally:
            port.release()

    def on_signal(self, signum: int, frame: FrameType | None) -> None:
        """Only set the flag: the loop notices within one poll interval."""
        self.worker.shutdown = True
