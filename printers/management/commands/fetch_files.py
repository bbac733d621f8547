"""`manage.py fetch_files --worker-host NAME`: a worker host's job files, fetched."""

from __future__ import annotations

import signal
from pathlib import Path
from typing import TYPE_CHECKING, Any

from django.conf import settings
from django.core.management.base import BaseCommand, CommandError

from jobs import hostcache
from printers.fetcher import Fetcher
from printers.hosts import WorkerHost

if TYPE_CHECKING:
    from argparse import ArgumentParser
    from types import FrameType


class Command(BaseCommand):
    help = (
        "Fetch the files of the jobs a worker host's printers will print from the "
        "control plane (PRINTHOST_CONTROL_URL, PRINTHOST_HOST_KEY) into its cache."
    )

    def add_arguments(self, parser: ArgumentParser) -> None:
        parser.add_argument("--worker-host", required=True, metavar="NAME")
        parser.add_argument(
            "--once", action="store_true", help="one pass, then exit (for scripts)"
        )

    def handle(self, *args: Any, **options: Any) -> None:
        name = options["worker_host"]
        if not WorkerHost.objects.filter(name=name).exists():
            raise CommandError(f"no worker host named {name!r}")
        if not settings.PRINTHOST_CONTROL_URL or not settings.PRINTHOST_HOST_KEY:
            raise CommandError(
                "a worker host fetches its files from the control plane: set "
                "PRINTHOST_CONTROL_URL and PRINTHOST_HOST_KEY (manage.py worker_host "
                "add NAME shows the key)"
            )
        try:
            fetcher = Fetcher(
                name,
                control_url=settings.PRINTHOST_CONTROL_URL,
                key=settings.PRINTHOST_HOST_KEY,
                cache=hostcache.cache_dir(),
                cap_bytes=settings.PRINTHOST_FILE_CACHE_BYTES,
            )
        except ValueError as error:
            raise CommandError(str(error)) from None
        if options["once"]:
            arrived = fetcher.step()
            self.stdout.write(f"{arrived} file(s) fetched into {_shown(fetcher)}")
            return
        self._stop = False
        signal.signal(signal.SIGTERM, self.on_signal)
        signal.signal(signal.SIGINT, self.on_signal)
        fetcher.run(lambda: self._stop)

    def on_signal(self, signum: int, frame: FrameType | None) -> None:
        self._stop = True


def _shown(fetcher: Fetcher) -> str:
    return str(Path("<data dir>") / fetcher.cache.relative_to(settings.DATA_DIR))
