"""The jobs app: stored G-code files spooled per printer."""

from __future__ import annotations

from typing import Any

from django.apps import AppConfig
from django.db.models.signals import post_save


class JobsConfig(AppConfig):
    name = "jobs"
    default_auto_field = "django.db.models.BigAutoField"

    def ready(self) -> None:
        from jobs.models import Job

        post_save.connect(_job_written, sender=Job, dispatch_uid="printhost-doorbell")


def _job_written(sender: type, instance: Any, **kwargs: Any) -> None:
    """A job saved queued wakes its printer's worker at commit (printers/doorbell.py)."""
    if instance.state == "queued":
        from printers.doorbell import ring_at_commit

        ring_at_commit(instance.printer_id, using=kwargs.get("using") or "default")
