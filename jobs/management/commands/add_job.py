"""`manage.py add_job <slug> <file>`: check a G-code file and queue it on a printer."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from django.core.management.base import BaseCommand, CommandError

from jobs.gcode import BadGcode
from jobs.services import enqueue_job
from printers.models import Printer

if TYPE_CHECKING:
    from argparse import ArgumentParser


class Command(BaseCommand):
    help = "Queue a G-code file on a printer (checked first: empty, binary, too long)."

    def add_arguments(self, parser: ArgumentParser) -> None:
        parser.add_argument("slug")
        parser.add_argument("file")
        parser.add_argument("--name", default="")

    def handle(self, *args: Any, **options: Any) -> None:
        try:
            printer = Printer.objects.get(slug=options["slug"])
        except Printer.DoesNotExist:
            raise CommandError(f"unknown printer {options['slug']!r}") from None
        source = Path(options["file"])
        if not source.is_file():
            raise CommandError(f"{source}: no such file")
        try:
            job = enqueue_job(printer, source, name=options["name"], origin="cli")
        except BadGcode as error:
            raise CommandError(str(error)) from None
        self.stdout.write(f"queued job {job.pk}: {job.name}, {job.line_count} commands")
