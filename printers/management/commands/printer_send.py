"""`manage.py printer_send <slug> <command>`: queue a command and print the reply."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

from django.core.management.base import BaseCommand, CommandError

from jobs.commands import request_action, send_command
from printers.models import Printer, QueuedCommand

if TYPE_CHECKING:
    from argparse import ArgumentParser


class Command(BaseCommand):
    help = "Send a command ([ESP700]/[ESP701] too) or an action to a printer's worker."

    def add_arguments(self, parser: ArgumentParser) -> None:
        parser.add_argument("slug")
        parser.add_argument(
            "command", help="G-code, [ESP701]..., or an action with --action"
        )
        parser.add_argument(
            "--action", action="store_true", help="COMMAND is an action"
        )
        parser.add_argument("--wait", type=float, default=10.0, help="seconds to wait")

    def handle(self, *args: Any, **options: Any) -> None:
        try:
            printer = Printer.objects.get(slug=options["slug"])
        except Printer.DoesNotExist:
            raise CommandError(f"unknown printer {options['slug']!r}") from None
        try:
            if options["action"]:
                row = request_action(printer, options["command"], origin="cli")
            else:
                row = send_command(printer, options["command"], origin="cli")
        except ValueError as error:
            raise CommandError(str(error)) from None
        deadline = time.monotonic() + options["wait"]
        done = {QueuedCommand.State.DONE, QueuedCommand.State.FAILED}
        while time.monotonic() < deadline:
            row.refresh_from_db()
            if row.state in done:
                break
            time.sleep(0.05)
        else:
            raise CommandError(
                f"no answer within {options['wait']} s (is the worker running?)"
            )
        if row.state == QueuedCommand.State.FAILED:
            raise CommandError(row.reply)
        self.stdout.write(row.reply)
