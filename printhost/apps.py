"""The printhost app: accounts (API keys, roles, app-key pairing) and the audit log."""

from __future__ import annotations

from django.apps import AppConfig


class PrinthostConfig(AppConfig):
    name = "printhost"
    default_auto_field = "django.db.models.BigAutoField"
