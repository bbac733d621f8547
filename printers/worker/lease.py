"""A worker's claim on its printer: a row lease taken with a conditional UPDATE."""

from __future__ import annotations

import os
import socket
import uuid
from datetime import timedelta

from django.db.models import Q
from django.utils import timezone

from printers.models import Printer


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

    def holder(self) -> str:
        return (
            Printer.objects.filter(pk=self.printer_id)
            .values_list("lease_owner", flat=True)
            .first()
            or ""
        )

    def renew_if_due(self, now: float) -> None:
        """Renew a third of the way through; raise LeaseLost if someone else has it."""
        if now < self.renew_at:
            return
        if not self.claim():
            raise LeaseLost(
                f"printer {self.printer_id} is now driven by {self.holder()}"
            )
        self.renew_at = now + self.seconds / 3

    def release(self) -> None:
        Printer.objects.filter(pk=self.printer_id, lease_owner=self.owner).update(
            lease_owner="", lease_expires_at=None
        )
