"""The printers app: printers, their workers, protocols and simulators."""

from __future__ import annotations

from typing import Any

from django.apps import AppConfig
from django.db.models.signals import post_save


class PrintersConfig(AppConfig):
    name = "printers"
    default_auto_field = "django.db.models.BigAutoField"

    def ready(self) -> None:
        from printers.models import QueuedCommand

        post_save.connect(
            _request_written, sender=QueuedCommand, dispatch_uid="printhost-doorbell"
        )


def _request_written(sender: type, instance: Any, **kwargs: Any) -> None:
    """A new request wakes its printer's worker at commit (printers/doorbell.py)."""
    if kwargs.get("created"):
        from printers.doorbell import ring_at_commit

        ring_at_commit(instance.printer_id, using=kwargs.get("using") or "default")
