"""`manage.py export_job <id> --driver marlin out.gcode`: a job's exact wire bytes."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from django.conf import settings
from django.core.management.base import BaseCommand, CommandError

from jobs.gcode import BadGcode, iter_commands
from jobs.models import Job
from printers.driver import FileDriver, LinkConfig
from printers.protocol.errors import CommandRejected

if TYPE_CHECKING:
    from argparse import ArgumentParser


class Command(BaseCommand):
    help = "Write the bytes a job would send to its printer (line numbers, checksums)."

    def add_arguments(self, parser: ArgumentParser) -> None:
        parser.add_argument("job_id", type=int)
        parser.add_argument("output", help="file to write, - for stdout")
        parser.add_argument(
            "--driver",
            choices=["marlin", "grbl"],
            help="firmware to write for (default: the job's printer's)",
        )

    def handle(self, *args: Any, **options: Any) -> None:
        try:
            job = Job.objects.select_related("printer").get(pk=options["job_id"])
        except Job.DoesNotExist:
            raise CommandError(f"no job {options['job_id']}") from None
        try:
            path = job.path
        except BadGcode as error:
            raise CommandError(f"job {job.pk}: {error}") from None
        if not path.is_file():
            raise CommandError(f"job {job.pk}: its file {job.file} is missing")
        output = options["output"]
        storage = Path(settings.JOB_STORAGE_DIR).resolve()
        if output != "-" and Path(output).resolve().is_relative_to(storage):
            raise CommandError(
                f"{output}: inside the job storage; write the export somewhere else "
                "(it would overwrite or add a job file)"
            )
        config = LinkConfig.from_printer(job.printer)
        if options["driver"]:
            config = replace(config, firmware=options["driver"])
        config = replace(config, checksums="always")
        commands = (c.text for c in iter_commands(path))
        try:
            count = self._write(config, commands, output)
        except CommandRejected as error:
            raise CommandError(f"job {job.pk}: {error}") from None
        self.stderr.write(f"wrote {count} lines for job {job.pk}")

    def _write(self, config: LinkConfig, commands: Any, output: str) -> int:
        if output == "-":
            return FileDriver(config, sys.stdout.buffer).run(commands)
        with Path(output).open("wb") as out:
            return FileDriver(config, out).run(commands)
