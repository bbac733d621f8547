"""`manage.py simulate_printer marlin --link ./printer0 ...`: the firmware simulator, by Django."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING, Any

from django.core.management.base import BaseCommand, CommandError

from printers.simulator.cli import main

if TYPE_CHECKING:
    from argparse import ArgumentParser


class Command(BaseCommand):
    help = "Simulate a Marlin or GRBL controller on a pty/TCP port (see --help)."

    def run_from_argv(self, argv: list[str]) -> None:
        """Hand every argument to the simulator's own parser (it has its own --help)."""
        sys.exit(main(argv[2:], prog=f"{argv[0]} {argv[1]}"))

    def add_arguments(self, parser: ArgumentParser) -> None:
        parser.add_argument("args", nargs=argparse.REMAINDER)

    def handle(self, *args: Any, **options: Any) -> None:
        """For call_command("simulate_printer", "marlin", "--link", ...)."""
        code = main(list(args), prog="simulate_printer")
        if code:
            raise CommandError(f"simulator exited with status {code}", returncode=code)
