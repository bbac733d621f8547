"""Upkeep: analysis rows, thumbnails and previews of SHA-256s no stored job file has
any more are removed by beat; a pending or running analysis, and a folder written
within the last hour, are kept."""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
from django.conf import settings
from django.utils import timezone

from jobs.models import FileAnalysis, Job
from jobs.upkeep import remove_orphaned_analyses
from tests.upkeep.conftest import age, analysed

if TYPE_CHECKING:
    from collections.abc import Callable

    from printers.models import Printer

pytestmark = pytest.mark.django_db

LONG_AGO = timedelta(days=3)


def test_the_analysis_of_a_deleted_job_goes_and_that_of_a_stored_file_stays(
    make_printer: Callable[..., Printer], make_job: Callable[..., Job]
) -> None:
    now = timezone.now()
    printer = make_printer()
    stored = make_job(printer, "G1 X2\n", "stored.gcode")
    deleted = make_job(printer, "G1 X1\n", "deleted.gcode")
    stored_folder = analysed(stored.sha256, at=now - LONG_AGO)
    deleted_folder = analysed(deleted.sha256, at=now - LONG_AGO)
    deleted.delete()

    # One row per batch: the orphan is on the second page.
    assert remove_orphaned_analyses(now=now, batch=1) == {"analyses": 1, "folders": 1}

    assert not deleted_folder.exists()
    assert not FileAnalysis.objects.filter(sha256=deleted.sha256).exists()
    assert stored_folder.exists()
    assert FileAnalysis.objects.get(sha256=stored.sha256).state == "done"


def test_the_analysis_of_a_file_the_upkeep_removed_goes_unless_another_copy_is_stored(
    make_printer: Callable[..., Printer], make_job: Callable[..., Job]
) -> None:
    now = timezone.now()
    printer = make_printer()
    removed = make_job(printer, "G1 X1\n", "a.gcode")
    copy_removed = make_job(printer, "G1 X2\n", "b.gcode")
    copy_stored = make_job(printer, "G1 X2\n", "c.gcode")
    Job.objects.filter(pk__in=[removed.pk, copy_removed.pk]).update(
        state="completed", file_removed_at=now - LONG_AGO
    )
    gone = analysed(removed.sha256, at=now - LONG_AGO)
    kept = analysed(copy_stored.sha256, at=now - LONG_AGO)

    assert remove_orphaned_analyses(now=now, batch=1) == {"analyses": 1, "folders": 1}
    assert not gone.exists()
    assert kept.exists()


@pytest.mark.parametrize("state", ["pending", "running"])
def test_an_analysis_waiting_or_running_is_kept_even_without_a_file(
    make_printer: Callable[..., Printer], make_job: Callable[..., Job], state: str
) -> None:
    now = timezone.now()
    job = make_job(make_printer(), "G1 X1\n")
    folder = analysed(job.sha256, at=now - LONG_AGO, state=state)
    job.delete()

    assert remove_orphaned_analyses(now=now) == {"analyses": 0, "folders": 0}
    assert folder.exists()
    assert FileAnalysis.objects.get(sha256=job.sha256).state == state


def test_folders_without_a_row_go_once_nothing_in_them_changed_for_an_hour(
    make_printer: Callable[..., Printer],
) -> None:
    now = timezone.now()
    root = Path(settings.ANALYSIS_DIR)
    old = analysed("a" * 64, at=now - timedelta(hours=1, seconds=1))
    at_limit = analysed("b" * 64, at=now - timedelta(hours=1))
    young = analysed("c" * 64, at=now - LONG_AGO)
    age(young / "toolpath-fff.bin", now - timedelta(minutes=1))  # being written
    FileAnalysis.objects.all().delete()
    not_ours = root / "not-a-sha256"
    not_ours.mkdir()
    age(not_ours, now - LONG_AGO)

    assert remove_orphaned_analyses(now=now) == {"analyses": 0, "folders": 1}
    assert not old.exists()
    assert at_limit.exists()
    assert young.exists()
    assert not_ours.exists()


def test_a_folder_whose_file_is_stored_is_kept_without_a_row(
    make_printer: Callable[..., Printer], make_job: Callable[..., Job]
) -> None:
    now = timezone.now()
    job = make_job(make_printer(), "G1 X1\n")
    folder = analysed(job.sha256, at=now - LONG_AGO)
    FileAnalysis.objects.all().delete()  # e.g. the row of an old motion profile
    assert remove_orphaned_analyses(now=now) == {"analyses": 0, "folders": 0}
    assert folder.exists()


def test_an_empty_or_missing_analysis_dir_is_fine(
    make_printer: Callable[..., Printer],
) -> None:
    assert not Path(settings.ANALYSIS_DIR).exists()
    assert remove_orphaned_analyses() == {"analyses": 0, "folders": 0}
