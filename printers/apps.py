"""The printers app: printers, their workers, protocols and simulators."""

from __future__ import annotations

from django.apps import AppConfig
from django.db.models.signals import post_save


class PrintersConfig(AppConfig):
    name = "printers"
    default_auto_field = "django.db.models.BigAutoField"

    def ready(self) -> None:
        from jobs.models import Job
        from printers.doorbell import ring_for_saved
        from printers.models import QueuedCommand

        for model in (QueuedCommand, Job):
            post_save.connect(ring_for_saved, sender=model, dispatch_uid="doorbell")
