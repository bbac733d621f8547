"""`manage.py run_dispatcher`: the farm's dispatcher, one loop, no threads.

Every `--interval` seconds (1 by default; at once again after a pass that gave a
job) it runs one pass over the farm queue (`jobs.farm.dispatch.Dispatcher`).
Several may run (one per control plane): the claim is atomic. A database that is
away costs passes, never the process: the error is logged (once a minute), the
connection dropped and the pass tried again after a backoff.
"""

from __future__ import annotations

import logging
import os
import signal
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from django.core.management.base import BaseCommand, CommandError
from django.db import DatabaseError, connection

from jobs.farm.dispatch import Dispatcher
from printhost.longrunning import close_failed_connections

if TYPE_CHECKING:
    from argparse import ArgumentParser
    from types import FrameType

    from jobs.farm.models import FarmJob
    from printers.models import Printer

logger = logging.getLogger("printhost.farm")

#: Longest wait after a failed pass (doubling from the interval).
MAX_BACKOFF = 30.0
#: A held claim (the test hook) lets go after this long at most.
HOLD_LIMIT = 120.0


def hold_until_removed(path: Path) -> Any:
    """A claim hook for tests: write *path* inside the claim's transaction, then wait
    until the file is removed (or the process is killed), at most `HOLD_LIMIT` s."""

    def hook(farm_job: FarmJob, printer: Printer) -> None:
        path.write_text(f"{os.getpid()} {farm_job.pk} {printer.slug}\n")
        deadline = time.monotonic() + HOLD_LIMIT
        while path.exists() and time.monotonic() < deadline:
            time.sleep(0.02)

    return hook


class Command(BaseCommand):
    help = "Give waiting farm jobs to free matching printers (one pass a second)."

    def add_arguments(self, parser: ArgumentParser) -> None:
        parser.add_argument(
            "--interval", type=float, default=1.0, help="seconds between passes"
        )
        parser.add_argument("--once", action="store_true", help="run one pass and exit")
        parser.add_argument(
            "--hold-claim",
            type=Path,
            default=None,
            help="tests only: inside a claim, write this file and wait until it is "
            "removed",
        )

    def handle(self, *args: Any, **options: Any) -> None:
        interval = options["interval"]
        if not 0.05 <= interval <= 60:
            raise CommandError(f"--interval must be 0.05 to 60 s, not {interval:g}")
        hold = options["hold_claim"]
        dispatcher = Dispatcher(hook=hold_until_removed(hold) if hold else None)
        if options["once"]:
            given = dispatcher.run_pass()
            self.stdout.write(f"{given} farm job(s) given to printers")
            return
        self.shutdown = False
        signal.signal(signal.SIGTERM, self.on_signal)
        signal.signal(signal.SIGINT, self.on_signal)
        logger.info("dispatcher %s: a pass every %g s", os.getpid(), interval)
        self.loop(dispatcher, interval)

    def loop(self, dispatcher: Dispatcher, interval: float) -> None:
        """Passes until a signal; a failed pass waits longer each time."""
        wait, last_logged = interval, 0.0
        while not self.shutdown:
            close_failed_connections()
            try:
                given = dispatcher.run_pass()
            except DatabaseError as error:
                if time.monotonic() - last_logged > 60:
                    logger.warning("dispatcher: pass failed (%s); retrying", error)
                    last_logged = time.monotonic()
                connection.close()
                wait = min(MAX_BACKOFF, wait * 2)
                self.sleep(wait)
                continue
            wait = interval
            if not given:
                self.sleep(interval)

    def sleep(self, seconds: float) -> None:
        """Wait, waking early for a signal (checked every 0.1 s)."""
        deadline = time.monotonic() + seconds
        while not self.shutdown and time.monotonic() < deadline:
            time.sleep(min(0.1, deadline - time.monotonic()))

    def on_signal(self, signum: int, frame: FrameType | None) -> None:
        """Only set the flag: the loop ends after its pass."""
        self.shutdown = True
