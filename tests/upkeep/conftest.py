"""Fixtures of the upkeep tests: jobs finished some time ago, analyses on disk."""

from __future__ import annotations

import os
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
from django.conf import settings
from django.contrib.auth import get_user_model

from jobs.models import FileAnalysis, Job
from printhost.access import issue_key
from printhost.models import PrinterRole, Role

if TYPE_CHECKING:
    from collections.abc import Callable


def age(path: Path, at: datetime) -> Path:
    """Set *path*'s mtime (and its files', for a folder) to *at*, to the nanosecond."""
    ns = (at - datetime(1970, 1, 1, tzinfo=UTC)) // timedelta(microseconds=1) * 1000
    if path.is_dir():
        for child in path.iterdir():
            os.utime(child, ns=(ns, ns))
    os.utime(path, ns=(ns, ns))
    return path


def finish(job: Job, state: str, at: datetime | None) -> Job:
    """The job in *state*, finished at *at* (as the worker writes it)."""
    Job.objects.filter(pk=job.pk).update(state=state, finished_at=at)
    job.refresh_from_db()
    return job


def analysed(sha256: str, *, at: datetime, state: str = "done") -> Path:
    """The analysis of *sha256* in *state*, with a thumbnail and a preview on disk
    last written at *at*; returns its folder."""
    row = FileAnalysis.objects.filter(sha256=sha256).first() or FileAnalysis(
        sha256=sha256, profile="0" * 16
    )
    row.state = state
    row.save()
    folder = Path(settings.ANALYSIS_DIR) / sha256
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "16x16.png").write_bytes(b"\x89PNG")
    (folder / "toolpath-fff.bin").write_bytes(b"\0" * 32)
    return age(folder, at)


@pytest.fixture
def operator_key(db: None) -> Callable[[], str]:
    """A raw API key of a fresh operator of every printer."""

    def make() -> str:
        user = get_user_model().objects.create_user(
            f"op{get_user_model().objects.count()}"
        )
        PrinterRole.objects.create(user=user, role=Role.OPERATOR, printer=None)
        return issue_key(user, "test")[1]

    return make
