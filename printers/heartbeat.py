"""A worker host's claim on its name, and its heartbeat (`runhost --worker-host`).

One runhost at a time may be a worker host: starting claims the `WorkerHost` row
(its `instance`, `hostname:pid:boot:random`) with a conditional UPDATE. Whether
the runhost that held the name before may be taken over:

H1  It ran on this computer since its last boot (same hostname and boot id): only
    if its process is gone.
H2  Its heartbeat is fresh, and H1 does not apply: never. A computer with the same
    hostname but another boot id is another computer (a copy of the same system
    image) as often as this one rebooted, and a reboot outlasts the heartbeat.
H3  Its heartbeat is stale and it ran on a computer of this name: yes (this one,
    rebooted).
H4  Its heartbeat is stale and it ran on another computer: only once an operator
    released the name (`manage.py worker_host release NAME`, or the admin), saying
    that computer is gone for good. A host cut off from the database is stale here
    and still drives its printers, whose ports are not this computer's.

Heartbeats are written and judged by the database's clock (printers/dbclock.py), as
leases are: a host whose own clock is off neither looks dead while it runs nor
alive once it stopped. Every `PRINTHOST_HEARTBEAT_SECONDS` the host writes its
version, load and printers on condition that the row still names it; if another
runhost took the name meanwhile, or it was released, this one stops (two hosts
must never run one printer's worker; the lease would stop the second from
driving it, this stops the second from trying).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import uuid
from pathlib import Path
from typing import Any

from django.conf import settings
from django.db.models.functions import Now

from printers.dbclock import database_now, learn_offset, now_plus
from printers.hosts import HEARTBEAT_STALE_SECONDS, WorkerHost
from printhost import __version__


class HostRefused(Exception):
    """This runhost may not be that worker host; the message says why."""


def make_instance() -> str:
    return f"{socket.gethostname()}:{os.getpid()}:{boot_id()}:{uuid.uuid4().hex[:6]}"


def boot_id() -> str:
    """This computer's boot, as Linux names it ("" where it does not)."""
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()[:8]
    except OSError:
        return ""


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


def heartbeat_load() -> dict[str, Any]:
    """`host_load()` and how far this computer's clock is from the database's
    (`clock_offset_s`, measured now; it also sets the offset this process's
    stamps use, printers/dbclock.py)."""
    load = host_load()
    offset = learn_offset()
    if offset is not None:
        load["clock_offset_s"] = round(offset, 2)
    return load


def _still_holds(instance: str, *, online: bool) -> str:
    """Why the runhost *instance* still holds its name (H1 to H4), or ""."""
    hostname, _, rest = instance.partition(":")
    parts = rest.split(":")
    pid_text = parts[0]
    # An instance written before boot ids were (hostname:pid:random) has none, nor
    # one from a system without them: the pid alone says whether it runs here.
    boot = (parts[1] or None) if len(parts) > 2 else None
    here = hostname == socket.gethostname()
    if here and boot in (boot_id() or None, None):
        try:
            pid = int(pid_text)
            os.kill(pid, 0)
        except (ValueError, ProcessLookupError):
            return ""
        except PermissionError:
            pass
        return f"runhost (pid {pid_text}) on this computer still runs it"
    if online:
        if here:
            return (
                f"it runs on a computer named {hostname} too (another computer, "
                "or this one before it restarted)"
            )
        return f"it runs on {hostname}"
    if here:
        return ""
    return f"it last ran on {hostname}, which may be cut off and still printing"


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
        now = database_now()
        online = host.online_at(now)
        why = _still_holds(host.instance, online=online) if held else ""
        if why:
            age = host.heartbeat_age(now) or 0.0
            if online:
                raise HostRefused(
                    f"worker host {self.name} is already running ({why}, heartbeat "
                    f"{age:.0f} s ago): two hosts must not drive the same printers; "
                    "stop it first (a clean stop gives the name back)"
                )
            raise HostRefused(
                f"worker host {self.name}: {why} (heartbeat {age:.0f} s ago). If "
                "that computer is gone for good and its printers are plugged in "
                "here now, release the name on the control plane (manage.py "
                f"worker_host release {self.name}, or the admin), then start again"
            )
        won = WorkerHost.objects.filter(pk=host.pk, instance=host.instance).update(
            instance=self.instance,
            hostname=socket.gethostname(),
            version=__version__,
            started_at=Now(),
            seen_at=Now(),
            load=heartbeat_load(),
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
                seen_at=Now(), load=heartbeat_load(), printers=printers
            )
            == 1
        )

    def lost_reason(self) -> str:
        """Why a beat found no row: another runhost took the name, or (the row still
        names this one) the database role's row policies no longer cover it."""
        instance = (
            WorkerHost.objects.filter(name=self.name)
            .values_list("instance", flat=True)
            .first()
        )
        if instance == self.instance:
            return (
                f"worker host {self.name}: its database role may no longer write "
                f"its row (its grants name other hosts: manage.py worker_host "
                f"grants ROLE {self.name})"
            )
        return f"worker host {self.name} was claimed by another runhost"

    def leave(self) -> None:
        """Give the name back (a clean stop): a restart need not wait."""
        WorkerHost.objects.filter(name=self.name, instance=self.instance).update(
            instance="", printers={}, seen_at=now_plus(-HEARTBEAT_STALE_SECONDS)
        )


def release(host: WorkerHost) -> None:
    """An operator says the computer that last ran *host* is gone for good (H4):
    the next runhost of the name may start anywhere. HostRefused while its
    heartbeat is fresh (it runs: stop it instead)."""
    host.refresh_from_db()
    now = database_now()
    if host.online_at(now):
        age = host.heartbeat_age(now) or 0.0
        raise HostRefused(
            f"worker host {host.name} is running on {host.hostname or 'its computer'} "
            f"(heartbeat {age:.0f} s ago): stop it instead; a clean stop gives the "
            "name back"
        )
    WorkerHost.objects.filter(pk=host.pk, instance=host.instance).update(
        instance="", printers={}
    )
