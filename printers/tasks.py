"""Celery tasks of the printers app: the upkeep of its tables (`printers.upkeep`),
scheduled by beat (CELERY_BEAT_SCHEDULE)."""

from __future__ import annotations

from celery import shared_task

from printers import upkeep


@shared_task
def trim_response_logs() -> dict[str, int]:
    """Each printer's response log down to its `response_log_limit` lines."""
    return upkeep.trim_response_logs()


@shared_task
def prune_temperature_samples() -> dict[str, int]:
    """Temperature samples older than PRINTHOST_TEMPERATURE_KEEP_HOURS."""
    return upkeep.prune_temperature_samples()
