"""Celery tasks of the jobs app: thin wrappers over `jobs.analysing`."""

from __future__ import annotations

from celery import shared_task
from celery.signals import worker_ready
from django.db import DatabaseError

from jobs import analysing


@shared_task(
    autoretry_for=(DatabaseError,),
    retry_backoff=2,
    retry_backoff_max=300,
    retry_jitter=True,
    max_retries=10,
)
def analyse_file(analysis_id: int) -> str:
    """Analyse one stored file (idempotent: a done or busy analysis is skipped)."""
    return analysing.run(analysis_id)


@shared_task
def sweep_analyses() -> int:
    """Send again the analyses a dead worker or a lost message left (beat, 30 s)."""
    return analysing.sweep()


@worker_ready.connect
def _sweep_at_start(**_kwargs: object) -> None:
    """A worker that starts picks up what the last one was doing when it died."""
    analysing.sweep()
