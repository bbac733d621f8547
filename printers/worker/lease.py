"""A worker's claim on its printer: a row lease taken with a conditional UPDATE.

Every write the worker makes for its printer (job outcome and progress, printer
state, response log) runs in `Lease.held()`: one transaction that first touches the
printer row on the condition that this worker still holds an unexpired lease. That
row lock (PostgreSQL) or write lock (SQLite) is kept until the commit, so a takeover
is ordered strictly before or after the write: after it, the write is refused.

Locally the worker also knows how long its lease surely lasts (`valid_until`, counted
from before the renewing UPDATE), and touches the port only inside that time.
"""

from __future__ import annotations

import os
import socket
import uuid
from contextlib import contextmanager
from datetime import timedelta
from typing import TYPE_CHECKING

from django.db import transaction
from django.db.models import Q
from django.utils import timezone

from printers.models import Printer

if TYPE_CHECKING:
    from collections.abc import Iterator

#: Renew this many times per lease period (a renewal that waits behind a slow write
#: or a lock still has most of the period left).
RENEWALS_PER_LEASE = 5


def make_owner() -> str:
    """A name for this worker that says where it runs: host:pid:random."""
    return f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:6]}"


class LeaseLost(Exception):
    """Another worker holds the printer; this one must stop driving it."""


class Lease:
    """Two workers can never drive one printer: whoever renews in time keeps it."""

    def __init__(self, printer_id: int, owner: str, seconds: float) -> None:
        self.printer_id = printer_id
        self.owner = owner
        self.seconds = seconds
        self.renew_at = 0.0
        #: Monotonic time until which the lease surely holds (0: not held).
        self.valid_until = 0.0
        self.lost = False

    def claim(self) -> bool:
        """Take the printer if it is free, expired or already ours (one UPDATE)."""
        now = timezone.now()
        free = (
            Q(lease_owner="") | Q(lease_owner=self.owner) | Q(lease_expires_at__lt=now)
        )
        won = (
            Printer.objects.filter(pk=self.printer_id)
            .filter(free)
            .update(
                lease_owner=self.owner,
                lease_expires_at=now + timedelta(seconds=self.seconds),
                worker_seen_at=now,
            )
        )
        return won == 1

    def _extend(self) -> bool:
        """Renew: only while the row still names this worker (never re-take it)."""
        now = timezone.now()
        return (
            Printer.objects.filter(pk=self.printer_id, lease_owner=self.owner).update(
                lease_expires_at=now + timedelta(seconds=self.seconds),
                worker_seen_at=now,
            )
            == 1
        )

    def holder(self) -> str:
        return (
            Printer.objects.filter(pk=self.printer_id)
            .values_list("lease_owner", flat=True)
            .first()
            or ""
        )

    def take(self, now: float) -> None:
        """Claim or renew at monotonic time *now* (read before the UPDATE)."""
        if self.lost:
            raise LeaseLost(f"printer {self.printer_id}: this worker lost its lease")
        won = self._extend() if self.valid_until else self.claim()
        if not won:
            self.lost = True
            raise LeaseLost(
                f"printer {self.printer_id} is now driven by {self.holder() or 'nobody'}"
            )
        self.valid_until = now + self.seconds
        self.renew_at = now + self.seconds / RENEWALS_PER_LEASE

    def renew_if_due(self, now: float) -> None:
        """Renew a fifth of the way through; raise LeaseLost if someone else has it."""
        if now >= self.renew_at:
            self.take(now)

    def ensure(self, now: float) -> None:
        """Before touching the port: renew at once if the lease may have run out."""
        if self.lost:
            raise LeaseLost(f"printer {self.printer_id}: this worker lost its lease")
        if now >= self.valid_until:
            self.take(now)

    def check(self) -> None:
        """A read: raise LeaseLost unless the row still names this worker, unexpired.

        Cheap enough for every poll; it narrows (the conditional writes in `held()`
        close) the window in which a worker could act after a takeover.
        """
        if self.lost:
            raise LeaseLost(f"printer {self.printer_id}: this worker lost its lease")
        mine = Printer.objects.filter(
            pk=self.printer_id,
            lease_owner=self.owner,
            lease_expires_at__gt=timezone.now(),
        ).exists()
        if not mine:
            self.lost = True
            raise LeaseLost(
                f"printer {self.printer_id}: lease lost "
                f"(now held by {self.holder() or 'nobody'})"
            )

    @contextmanager
    def held(self) -> Iterator[None]:
        """A transaction that commits only while this worker holds the lease."""
        if self.lost:
            raise LeaseLost(f"printer {self.printer_id}: this worker lost its lease")
        with transaction.atomic():
            now = timezone.now()
            still = Printer.objects.filter(
                pk=self.printer_id, lease_owner=self.owner, lease_expires_at__gt=now
            ).update(worker_seen_at=now)
            if still != 1:
                self.lost = True
                raise LeaseLost(
                    f"printer {self.printer_id}: lease lost "
                    f"(now held by {self.holder() or 'nobody'})"
                )
            yield

    def release(self) -> None:
        Printer.objects.filter(pk=self.printer_id, lease_owner=self.owner).update(
            lease_owner="", lease_expires_at=None
        )
        self.valid_until = 0.0
