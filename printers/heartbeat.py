"""A worker host's claim on its name, and its heartbeat (`runhost --worker-host`).

One runhost at a time may be a worker host: starting claims the `WorkerHost` row
(its `instance`) with a conditional UPDATE, refused while another runhost holds
the name and is alive: its heartbeat is fresh and it runs on another computer, or
on this one with its process still there. Every `PRINTHOST_HEARTBEAT_SECONDS` the
host writes its version, load and printers on condition that the row still names
it; if another runhost took the name meanwhile, this one stops (two hosts must
never run one printer's worker; the lease would stop the second from driving it,
this stops the second from trying).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import uuid
from datetime import timedelta
from pathlib import Path
from typing import Any

from django.conf import settings
from django.utils import timezone

from printers.hosts import HEARTBEAT_STALE_SECONDS, WorkerHost
from printhost import __version__


class HostRefused(Exception):
    """This runhost may not be that worker host; the message says why."""


def make_instance() -> str:
    return f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:6]}"


def host_load() -> dict[str, Any]:
    """What the dashboard shows of a host's load: load averages, CPUs, memory, disk."""
    load: dict[str, Any] = {"cpus": os.cpu_count() or 1}
    with contextlib.suppress(OSError):
        load["loadavg"] = [round(value, 2) for value in os.getloadavg()]
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                load["memory_free_mb"] = int(line.split()[1]) // 1024
    except OSError:
        pass
    with contextlib.suppress(OSError):
        load["disk_free_mb"] = shutil.disk_usage(settings.DATA_DIR).free // 1024**2
    return load


def _alive_elsewhere(instance: str) -> str:
    """Why *instance* (hostname:pid:random) still counts as running, or ""."""
    hostname, _, rest = instance.partition(":")
    pid_text = rest.partition(":")[0]
    if hostname != socket.gethostname():
        return f"it runs on {hostname}"
    try:
        pid = int(pid_text)
        os.kill(pid, 0)
    except (ValueError, ProcessLookupError):
        return ""
    except PermissionError:
        pass
    return f"runhost (pid {pid_text}) on this computer still runs it"


class HostRegistration:
    """This runhost as the worker host *name*: claim, heartbeats, leaving."""

    def __init__(self, name: str, instance: str = "") -> None:
        self.name = name
        self.instance = instance or make_instance()

    def claim(self) -> WorkerHost:
        """Take the name, or HostRefused with what to do about it."""
        host = WorkerHost.objects.filter(name=self.name).first()
        if host is None:
            known = ", ".join(WorkerHost.objects.values_list("name", flat=True))
            raise HostRefused(
                f"no worker host named {self.name!r} (known: {known or 'none'}); "
                f"add it on the control plane: manage.py worker_host add {self.name}"
            )
        if not host.enabled:
            raise HostRefused(f"worker host {self.name} is disabled (see the admin)")
        held = host.instance and host.instance != self.instance
        if held and host.online:
            why = _alive_elsewhere(host.instance)
            if why:
                age = host.heartbeat_age() or 0.0
                raise HostRefused(
                    f"worker host {self.name} is already running ({why}, heartbeat "
                    f"{age:.0f} s ago): two hosts must not drive the same printers; "
                    f"stop it, or wait {HEARTBEAT_STALE_SECONDS:.0f} s after it stopped"
                )
        now = timezone.now()
        won = WorkerHost.objects.filter(pk=host.pk, instance=host.instance).update(
            instance=self.instance,
            hostname=socket.gethostname(),
            version=__version__,
            started_at=now,
            seen_at=now,
            load=host_load(),
            printers={},
        )
        if won != 1:
            raise HostRefused(
                f"worker host {self.name} was claimed by another runhost just now"
            )
        host.refresh_from_db()
        return host

    def beat(self, printers: dict[str, Any]) -> bool:
        """Write the heartbeat; False if another runhost holds the name now."""
        return (
            WorkerHost.objects.filter(name=self.name, instance=self.instance).update(
                seen_at=timezone.now(), load=host_load(), printers=printers
            )
            == 1
        )

    def leave(self) -> None:
        """Give the name back (a clean stop): a restart need not wait."""
        WorkerHost.objects.filter(name=self.name, instance=self.instance).update(
            instance="", printers={}, seen_at=timezone.now() - _STALE
        )


_STALE = timedelta(seconds=HEARTBEAT_STALE_SECONDS)
