"""Upkeep: partial uploads untouched for PRINTHOST_UPLOAD_EXPIRE_HOURS (24 h) are
removed with their files by beat; one still being written is kept, and opening an
upload (a request) no longer removes anything."""

from __future__ import annotations

from datetime import timedelta
from typing import TYPE_CHECKING

import pytest
from django.utils import timezone

from jobs import uploads as sessions
from jobs.models import Upload
from jobs.upkeep import expire_uploads
from tests.upkeep.conftest import age

if TYPE_CHECKING:
    from collections.abc import Callable
    from datetime import datetime
    from pathlib import Path

    from printers.models import Printer

pytestmark = pytest.mark.django_db


def session(
    printer: Printer, name: str, *, touched: datetime, written: datetime
) -> Upload:
    """An upload whose row was last updated at *touched* and whose part file was last
    written at *written*."""
    upload = sessions.open_upload(printer, name, size=100)
    upload.partial_path.write_bytes(b"G28\n")
    age(upload.partial_path, written)
    Upload.objects.filter(pk=upload.pk).update(updated_at=touched)
    return upload


def aged(path: Path, at: datetime) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"G1 X1\n")
    return age(path, at)


def test_sessions_untouched_for_a_day_go_with_their_files(
    make_printer: Callable[..., Printer],
) -> None:
    now = timezone.now()
    printer = make_printer()
    day = timedelta(hours=24)
    old = session(printer, "old.gcode", touched=now - 2 * day, written=now - 2 * day)
    just_over = session(
        printer, "over.gcode", touched=now - day - timedelta(seconds=1),
        written=now - day - timedelta(seconds=1),
    )  # fmt: skip
    at_limit = session(printer, "limit.gcode", touched=now - day, written=now - 2 * day)
    recent = session(
        printer, "recent.gcode", touched=now - timedelta(hours=1),
        written=now - timedelta(hours=1),
    )  # fmt: skip

    assert expire_uploads(now=now, batch=1) == {"uploads": 2, "stray_files": 0}

    assert set(Upload.objects.values_list("pk", flat=True)) == {at_limit.pk, recent.pk}
    assert not old.partial_path.exists()
    assert not just_over.partial_path.exists()
    assert at_limit.partial_path.exists()
    assert recent.partial_path.exists()


def test_a_session_whose_file_is_still_being_written_is_kept(
    make_printer: Callable[..., Printer],
) -> None:
    now = timezone.now()
    printer = make_printer()
    # The row's time is set when a chunk ends; a long chunk moves the file first.
    writing = session(
        printer, "writing.gcode", touched=now - timedelta(days=2),
        written=now - timedelta(minutes=1),
    )  # fmt: skip
    written_at_limit = session(
        printer, "limit.gcode", touched=now - timedelta(days=2),
        written=now - timedelta(days=1),
    )  # fmt: skip
    # A session touched a moment ago owns its part file, however old the file is.
    touched = session(
        printer, "touched.gcode", touched=now - timedelta(minutes=1),
        written=now - timedelta(days=2),
    )  # fmt: skip
    assert expire_uploads(now=now) == {"uploads": 0, "stray_files": 0}
    assert Upload.objects.count() == 3
    for upload in (writing, written_at_limit, touched):
        assert upload.partial_path.exists(), upload.name


def test_the_age_is_a_setting(
    make_printer: Callable[..., Printer], settings: object
) -> None:
    settings.PRINTHOST_UPLOAD_EXPIRE_HOURS = 2  # type: ignore[attr-defined]
    now = timezone.now()
    printer = make_printer()
    gone = session(printer, "a.gcode", touched=now - timedelta(hours=3),
                   written=now - timedelta(hours=3))  # fmt: skip
    kept = session(printer, "b.gcode", touched=now - timedelta(hours=1),
                   written=now - timedelta(hours=1))  # fmt: skip
    assert expire_uploads(now=now)["uploads"] == 1
    assert list(Upload.objects.values_list("pk", flat=True)) == [kept.pk]
    assert not gone.partial_path.exists()


def test_old_files_no_session_owns_go_and_job_files_stay(
    make_printer: Callable[..., Printer],
    make_job: Callable[..., object],
    storage: Path,
) -> None:
    now = timezone.now()
    printer = make_printer()
    folder = storage / printer.slug
    old, young = now - timedelta(days=2), now - timedelta(hours=1)
    orphan_part = aged(folder / ".uploads" / f"{'a' * 32}.part", old)
    young_part = aged(folder / ".uploads" / f"{'b' * 32}.part", young)
    at_limit = aged(folder / ".uploads" / f"{'e' * 32}.part", now - timedelta(days=1))
    dead_staging = aged(folder / f".upload-{'c' * 32}", old)
    young_staging = aged(folder / f".upload-{'d' * 32}", young)
    other_hidden = aged(folder / ".keep", old)
    job = make_job(printer, "G28\n")
    age(job.path, old)

    assert expire_uploads(now=now) == {"uploads": 0, "stray_files": 2}

    assert not orphan_part.exists()
    assert not dead_staging.exists()
    for path in (young_part, at_limit, young_staging, other_hidden, job.path):
        assert path.exists(), path


def test_opening_an_upload_removes_nothing(
    make_printer: Callable[..., Printer],
) -> None:
    now = timezone.now()
    printer = make_printer()
    old = session(printer, "old.gcode", touched=now - timedelta(days=2),
                  written=now - timedelta(days=2))  # fmt: skip
    sessions.open_upload(printer, "new.gcode", size=10)
    assert Upload.objects.filter(pk=old.pk).exists()
    assert old.partial_path.exists()
