"""`manage.py run_terminal`: the raw TCP terminals of every printer with a terminal port."""

from __future__ import annotations

import asyncio
import signal
from typing import TYPE_CHECKING, Any

from django.core.management.base import BaseCommand

from printers.terminal import TerminalServer

if TYPE_CHECKING:
    from argparse import ArgumentParser


class Command(BaseCommand):
    help = "Serve each printer's raw TCP terminal (API key as the first line)."

    def add_arguments(self, parser: ArgumentParser) -> None:
        parser.add_argument(
            "--bind",
            default=None,
            help="address to listen on (PRINTHOST_TERMINAL_BIND)",
        )

    def handle(self, *args: Any, **options: Any) -> None:
        asyncio.run(self.serve(options["bind"]))

    async def serve(self, bind: str | None) -> None:
        """Serve until SIGTERM/SIGINT, which only set the stop event."""
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(signum, stop.set)
        await TerminalServer(bind).run(stop)
