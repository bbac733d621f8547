"""Celery tasks of the jobs app: thin wrappers over `jobs.analysis_task` and
`jobs.analysing` (file analysis),
`jobs.resume.planning` (resume plans) and `jobs.upkeep` (periodic upkeep, scheduled
by beat: CELERY_BEAT_SCHEDULE)."""

from __future__ import annotations

from celery import shared_task
from celery.signals import worker_ready
from django.db import DatabaseError

from jobs import analysing, upkeep


@shared_task(
    autoretry_for=(DatabaseError,),
    retry_backoff=2,
    retry_backoff_max=300,
    retry_jitter=True,
    max_retries=10,
)
def analyse_file(analysis_id: int) -> str:
    """Analyse one stored file (idempotent: a done or busy analysis is skipped)."""
    # Here, not above: a process that only sends this task never loads the analyser.
    from jobs import analysis_task

    return analysis_task.run(analysis_id)


@shared_task
def sweep_analyses() -> int:
    """Send again the analyses a dead worker or a lost message left (beat, 30 s)."""
    return analysing.sweep()


@shared_task
def expire_uploads() -> dict[str, int]:
    """Partial uploads untouched for PRINTHOST_UPLOAD_EXPIRE_HOURS, with their files."""
    return upkeep.expire_uploads()


@shared_task
def remove_expired_job_files() -> dict[str, int]:
    """Finished jobs' files past their printer's `job_file_days` (rows stay)."""
    return upkeep.remove_expired_job_files()


@shared_task
def remove_orphaned_analyses() -> dict[str, int]:
    """Analysis rows, thumbnails and previews of files no job holds any more."""
    return upkeep.remove_orphaned_analyses()


@worker_ready.connect
def _sweep_at_start(**_kwargs: object) -> None:
    """A worker that starts picks up what the last one was doing when it died."""
    analysing.sweep()


@shared_task(
    autoretry_for=(DatabaseError,),
    retry_backoff=2,
    retry_backoff_max=60,
    max_retries=5,
)
def plan_resume(plan_id: int) -> str:
    """Rebuild the machine's state at a resume plan's line and write its preamble."""
    from jobs.resume.planning import make_plan

    return make_plan(plan_id)
