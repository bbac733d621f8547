"""Worker hosts: the computers on the shelves that printers are plugged into.

A printer names its worker host (`Printer.worker_host`; none = the control plane's
own runhost). `runhost --worker-host NAME` runs the workers of that host's printers
only and writes the host's heartbeat here every few seconds; the host fetches job
files from the control plane with the host's own key (stored as SHA-256, shown
once by `manage.py worker_host add NAME`).
"""

from __future__ import annotations

import hashlib
import json
import math
import secrets
from datetime import datetime, timedelta
from typing import Any

from django.core.validators import RegexValidator
from django.db import models

from printers.dbclock import shared_now

_NAME = RegexValidator(r"^[a-z0-9][a-z0-9_-]*$", "lowercase letters, digits, - and _")

#: A host whose heartbeat is older than this is shown offline.
HEARTBEAT_STALE_SECONDS = 30.0
#: A host whose clock is this far (s) from the database's is warned about.
CLOCK_WARN_SECONDS = 2.0
#: Digits of an integer a worker's JSON may hold as an int (more: a float).
_INT_DIGITS = 40
#: Characters of the key kept in clear to find its row (safe to show).
KEY_PREFIX_CHARS = 10


def key_digest(key: str) -> str:
    return hashlib.sha256(key.encode()).hexdigest()


class HostJSONDecoder(json.JSONDecoder):
    """JSON a worker writes (a heartbeat's load, a printer's temperatures and link
    figures): an integer of more digits than Python's int() reads (4,300) becomes a
    float instead of failing every page that reads the row (`number` then takes
    it for no value)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("parse_int", _host_int)
        super().__init__(*args, **kwargs)


def _host_int(digits: str) -> int | float:
    return int(digits) if len(digits) <= _INT_DIGITS else float(digits)


class HostJSONField(models.JSONField):
    """A JSONField a worker writes, read with HostJSONDecoder. Migrations see a
    plain JSONField: how a value is read is nothing to the database."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs["decoder"] = HostJSONDecoder
        super().__init__(*args, **kwargs)

    def deconstruct(self) -> Any:
        name, _, args, kwargs = super().deconstruct()
        kwargs.pop("decoder", None)
        return name, "django.db.models.JSONField", args, kwargs


def number(value: object) -> float | None:
    """*value* (from a JSON field a worker writes: a heartbeat's load, a
    printer's link figures) as a finite float, or None (missing, text, NaN, a
    bool)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    try:
        value = float(value)
    except OverflowError:  # an int of hundreds of digits
        return None
    return value if math.isfinite(value) else None


def load_figures(load: object) -> tuple[float | None, int | None]:
    """The one-minute load average and the CPU count of a heartbeat's `load`,
    each None unless it is a number (the host writes the row: a bad value must
    not break the pages that show it)."""
    load = load if isinstance(load, dict) else {}
    averages, cpus = load.get("loadavg"), number(load.get("cpus"))
    first = number(averages[0]) if isinstance(averages, list) and averages else None
    counted = cpus is not None and cpus >= 1 and cpus.is_integer()
    return first, int(cpus) if counted else None


class WorkerHost(models.Model):
    """One worker host: its key for file fetches and its last heartbeat."""

    name = models.SlugField(max_length=50, unique=True, validators=[_NAME])
    description = models.CharField(max_length=200, blank=True)
    enabled = models.BooleanField(
        default=True, help_text="a disabled host's runhost refuses to start"
    )
    key_prefix = models.CharField(max_length=32, blank=True, editable=False)
    key_hash = models.CharField(max_length=64, blank=True, editable=False)

    # Written by the host's runhost (the heartbeat).
    instance = models.CharField(
        max_length=200, blank=True, help_text="hostname:pid:random of the runhost"
    )
    hostname = models.CharField(max_length=255, blank=True)
    version = models.CharField(max_length=50, blank=True)
    started_at = models.DateTimeField(null=True, blank=True)
    seen_at = models.DateTimeField(null=True, blank=True)
    #: {"loadavg": [1, 5, 15], "cpus": n, "memory_mb": n, "disk_free_mb": n,
    #: "clock_offset_s": the database's clock minus the host's}
    load = HostJSONField(default=dict, blank=True)
    #: {slug: {"pid": n, "running": bool, "restarts": n}} as the host runs them.
    printers = HostJSONField(default=dict, blank=True)
    #: Where the host serves its own /metrics (host:port), for scrape configs.
    metrics_address = models.CharField(max_length=255, blank=True)

    class Meta:
        ordering = ["name"]

    def __str__(self) -> str:
        return self.name

    def issue_key(self) -> str:
        """A new key for this host (the old one stops working); shown only now."""
        key = f"ph_host_{secrets.token_urlsafe(24)}"
        self.key_prefix = key[: len("ph_host_") + KEY_PREFIX_CHARS]
        self.key_hash = key_digest(key)
        self.save(update_fields=["key_prefix", "key_hash"])
        return key

    def key_matches(self, key: str) -> bool:
        return bool(self.key_hash) and secrets.compare_digest(
            self.key_hash, key_digest(key)
        )

    @property
    def online(self) -> bool:
        return self.online_at(shared_now())

    def online_at(self, now: datetime) -> bool:
        """Heard within HEARTBEAT_STALE_SECONDS of *now* (the database's time, where
        it decides who may run the host: heartbeats are written by that clock)."""
        if self.seen_at is None:
            return False
        return now - self.seen_at < timedelta(seconds=HEARTBEAT_STALE_SECONDS)

    def heartbeat_age(self, now: datetime | None = None) -> float | None:
        """Seconds since the last heartbeat (None: never seen)."""
        if self.seen_at is None:
            return None
        return max(0.0, ((now or shared_now()) - self.seen_at).total_seconds())

    def clock_warning(self) -> str:
        """What the dashboard says of the host's clock when it is CLOCK_WARN_SECONDS
        or more from the database's ("" otherwise). The host stamps its prints and
        log by the database's clock all the same (printers/dbclock.py)."""
        load = self.load if isinstance(self.load, dict) else {}
        offset = load.get("clock_offset_s")
        if not isinstance(offset, int | float) or abs(offset) < CLOCK_WARN_SECONDS:
            return ""
        side = "behind" if offset > 0 else "ahead of"
        return f"its clock is {abs(offset):.0f} s {side} the database's: set up NTP"

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "description": self.description,
            "enabled": self.enabled,
            "online": self.online,
            "hostname": self.hostname,
            "version": self.version,
            "started_at": self.started_at.isoformat() if self.started_at else None,
            "seen_at": self.seen_at.isoformat() if self.seen_at else None,
            "heartbeat_age": self.heartbeat_age(),
            "load": self.load,
            "clock_warning": self.clock_warning(),
            "printers": self.printers,
        }
