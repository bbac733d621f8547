"""The printers app: printers, their workers, protocols and simulators."""

from __future__ import annotations

from django.apps import AppConfig


class PrintersConfig(AppConfig):
    name = "printers"
    default_auto_field = "django.db.models.BigAutoField"
