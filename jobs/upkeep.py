"""Upkeep of job files, partial uploads and analysis data, run by Celery beat
(`jobs/tasks.py`), never in a request or a printer's worker.

- `expire_uploads`: partial uploads (`Upload` rows and their part files) untouched
  for PRINTHOST_UPLOAD_EXPIRE_HOURS, and part or staging files no row owns any more.
- `remove_expired_job_files`: the stored file of finished jobs (completed, aborted,
  failed, interrupted) that ended more than their printer's `job_file_days` ago.
  The job row stays, marked `file_removed_at`, as history; a file that any other job
  still needs (queued, running, stored, or finished more recently: reprints share
  one path) is kept. The file's analysis goes with it when no other stored file has
  its SHA-256.
- `remove_orphaned_analyses`: `FileAnalysis` rows, thumbnails and toolpath previews
  of SHA-256s no stored job file has any more; a pending or running analysis and a
  folder written within `FOLDER_GRACE` are kept.

Each function returns what it removed (counts) and logs one line. Rows go in
bounded batches, each its own short transaction, so SQLite's write lock is never
held for long.
"""

from __future__ import annotations

import logging
import os
import re
import shutil
from datetime import UTC, datetime, timedelta
from pathlib import Path

from django.conf import settings
from django.db import transaction
from django.db.models import Exists, OuterRef, Q
from django.utils import timezone

from jobs.models import FINISHED_STATES, FarmJob, FileAnalysis, Job, ResumePlan, Upload
from jobs.paths import PathRefused, inside
from printers.models import Printer

logger = logging.getLogger("printhost.upkeep")

#: Rows handled by one statement (and one transaction) at most.
BATCH_ROWS = 500
#: An analysis folder changed this recently is left alone (an analysis may be
#: starting to write it for a file stored a moment ago).
FOLDER_GRACE = timedelta(hours=1)
#: Analyses in these states are finished: their data may go once nothing needs it.
_SETTLED = (FileAnalysis.State.DONE, FileAnalysis.State.FAILED)
_SHA256 = re.compile(r"^[0-9a-f]{64}$")
#: Left in a printer's storage by an upload that died before it became a job.
_STAGING = re.compile(r"^\.upload-[0-9a-f]{32}$")
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


# -- Partial uploads ------------------------------------------------------------------


def expire_uploads(
    *, now: datetime | None = None, batch: int = BATCH_ROWS
) -> dict[str, int]:
    """Delete partial uploads untouched for PRINTHOST_UPLOAD_EXPIRE_HOURS.

    An upload whose row or part file changed within that time is kept (a file still
    being written moves its mtime before the row's `updated_at`); exactly that old is
    kept too. Part files in `<storage>/<printer>/.uploads/` with no row, and staging
    files of uploads that died (`.upload-<hex>`), go once they are as old.
    Returns {"uploads": sessions removed, "stray_files": files without a row}.
    """
    cutoff = (now or timezone.now()) - timedelta(
        hours=settings.PRINTHOST_UPLOAD_EXPIRE_HOURS
    )
    removed = 0
    after = ""
    while True:
        stale = list(
            Upload.objects.filter(updated_at__lt=cutoff, pk__gt=after)
            .order_by("pk")
            .only("pk", "path")[:batch]
        )
        for upload in stale:
            removed += _expire_upload(upload, cutoff)
        if len(stale) < batch:
            break
        after = stale[-1].pk
    strays = _remove_stray_upload_files(cutoff)
    logger.info(
        "upkeep: %d partial upload(s) untouched for %g h removed, %d stray file(s)",
        removed,
        settings.PRINTHOST_UPLOAD_EXPIRE_HOURS,
        strays,
    )
    return {"uploads": removed, "stray_files": strays}


def _expire_upload(upload: Upload, cutoff: datetime) -> int:
    try:
        partial: Path | None = upload.partial_path
    except PathRefused:  # a row naming a place outside the storage: not ours to touch
        partial = None
    if partial is not None and _changed_since(partial, cutoff):
        return 0  # bytes still arriving: the row's time is set when a chunk ends
    # Conditional: a chunk that arrived meanwhile keeps the session.
    deleted, _ = Upload.objects.filter(pk=upload.pk, updated_at__lt=cutoff).delete()
    if deleted and partial is not None:
        partial.unlink(missing_ok=True)
    return 1 if deleted else 0


def _changed_since(path: Path, cutoff: datetime) -> bool:
    try:
        return path.stat().st_mtime_ns >= _ns(cutoff)
    except FileNotFoundError:
        return False


def _ns(moment: datetime) -> int:
    """*moment* as nanoseconds since the epoch, exactly (as st_mtime_ns counts)."""
    return (moment - _EPOCH) // timedelta(microseconds=1) * 1000


def _remove_stray_upload_files(cutoff: datetime) -> int:
    """Part files no `Upload` row owns and dead staging files, as old as *cutoff*."""
    root = Path(settings.JOB_STORAGE_DIR)
    removed = 0
    for printer_folder in _subfolders(root):
        folder = Path(printer_folder.path)
        candidates = [(entry, "staging") for entry in _files(folder)]
        candidates += [(entry, "part") for entry in _files(folder / ".uploads")]
        for entry, kind in candidates:
            name = entry.name
            if kind == "staging" and not _STAGING.match(name):
                continue
            if kind == "part" and not name.endswith(".part"):
                continue
            if entry.stat(follow_symlinks=False).st_mtime_ns >= _ns(cutoff):
                continue
            if kind == "part" and Upload.objects.filter(pk=name[:-5]).exists():
                continue  # its row decides (`_expire_upload`)
            Path(entry.path).unlink(missing_ok=True)
            removed += 1
    return removed


def _subfolders(root: Path) -> list[os.DirEntry[str]]:
    """The folders in *root*, symlinks to folders left out."""
    try:
        with os.scandir(root) as entries:
            return [e for e in entries if e.is_dir(follow_symlinks=False)]
    except FileNotFoundError:
        return []


def _files(folder: Path) -> list[os.DirEntry[str]]:
    """The regular files in *folder* (none when it is a symlink: never followed)."""
    if folder.is_symlink():
        return []
    try:
        with os.scandir(folder) as entries:
            return [e for e in entries if e.is_file(follow_symlinks=False)]
    except (FileNotFoundError, NotADirectoryError):
        return []


# -- Finished jobs' files -------------------------------------------------------------


def remove_expired_job_files(*, now: datetime | None = None) -> dict[str, int]:
    """Remove the stored files of finished jobs past their printer's `job_file_days`.

    A job is past it when it is completed, aborted, failed or interrupted and its
    `finished_at` is more than `job_file_days` days ago (exactly that long: kept;
    0 days: kept forever). A file goes only when every job naming it is past its
    own printer's retention; the jobs keep their rows, marked `file_removed_at`
    (a reprint then answers that the file was removed). The analysis data of a
    removed file's SHA-256 goes too, unless another stored file has it.
    Returns {"files", "jobs" (rows marked), "analyses", "folders"}.
    """
    now = now or timezone.now()
    files = jobs = 0
    freed: set[str] = set()
    for printer_id, days in _retentions():
        names = (
            Job.objects.filter(
                printer_id=printer_id,
                state__in=FINISHED_STATES,
                finished_at__lt=now - timedelta(days=days),
                file_removed_at__isnull=True,
            )
            .exclude(file="")
            .order_by("file")
            .values_list("file", flat=True)
            .distinct()
        )
        for name in list(names):
            marked, digests = _remove_job_file(name, now)
            if marked:
                files += 1
                jobs += marked
                freed |= digests
    analyses, folders = _remove_analyses(now, only=freed) if freed else (0, 0)
    logger.info(
        "upkeep: %d finished job file(s) past their printer's retention removed "
        "(%d job(s) kept as history), with %d analysis row(s) and %d folder(s)",
        files,
        jobs,
        analyses,
        folders,
    )
    return {"files": files, "jobs": jobs, "analyses": analyses, "folders": folders}


def _retentions() -> list[tuple[int, int]]:
    """(printer id, days) of every printer that keeps finished jobs' files a while."""
    return list(
        Printer.objects.filter(job_file_days__gt=0).values_list("pk", "job_file_days")
    )


def _remove_job_file(name: str, now: datetime) -> tuple[int, set[str]]:
    """Remove the stored file *name* if every job naming it is past its retention;
    returns (jobs marked, their SHA-256s); (0, set()) when it is kept."""
    try:
        path = inside(Path(settings.JOB_STORAGE_DIR), name)
    except PathRefused as error:
        logger.warning("upkeep: job file %r left alone: %s", name, error)
        return 0, set()
    try:
        with transaction.atomic():
            # Lock the rows naming the file (PostgreSQL; SQLite's write transaction
            # already excludes every other writer), then read them afresh: a reprint
            # committed while we waited for the lock is seen and keeps the file.
            list(
                Job.objects.select_for_update()
                .filter(file=name)
                .values_list("pk", flat=True)
            )
            sharing = list(
                Job.objects.filter(file=name).values_list(
                    "state",
                    "finished_at",
                    "file_removed_at",
                    "printer__job_file_days",
                    "sha256",
                )
            )
            if not all(_past_retention(*row[:4], now=now) for row in sharing):
                return 0, set()
            if _resume_needs(name):
                return 0, set()
            marked = Job.objects.filter(file=name, file_removed_at__isnull=True).update(
                file_removed_at=now
            )
            # Inside the transaction: a file that cannot be removed leaves the rows
            # unmarked, and the next run tries again.
            path.unlink(missing_ok=True)
    except OSError as error:
        logger.warning("upkeep: job file %s not removed: %s", name, error)
        return 0, set()
    return marked, {row[4] for row in sharing if row[4]}


def _resume_needs(name: str) -> bool:
    """A run interrupted and not resumed yet, or a resume plan not started, still
    needs the file *name*: a part waits on a bed for it, whatever its age."""
    waiting = Job.objects.filter(
        file=name, state=Job.State.INTERRUPTED, file_removed_at__isnull=True
    ).exclude(Exists(Job.objects.filter(resume_of=OuterRef("pk"))))
    planned = ResumePlan.objects.filter(
        job__file=name,
        state__in=[ResumePlan.State.PENDING, ResumePlan.State.READY],
    )
    return waiting.exists() or planned.exists()


def _past_retention(
    state: str,
    finished_at: datetime | None,
    removed_at: datetime | None,
    days: int,
    *,
    now: datetime,
) -> bool:
    if removed_at is not None:
        return True  # its file is already gone: it needs nothing
    if state not in FINISHED_STATES or finished_at is None or days <= 0:
        return False
    return finished_at < now - timedelta(days=days)


# -- Orphaned analysis data -----------------------------------------------------------


def remove_orphaned_analyses(
    *, now: datetime | None = None, batch: int = BATCH_ROWS
) -> dict[str, int]:
    """Remove analyses of SHA-256s that no stored job file has any more.

    A `FileAnalysis` row goes when it is done or failed and no job holds a stored
    file (not removed) with its SHA-256; a pending or running one is kept. A folder
    of thumbnails and previews under PRINTHOST_ANALYSIS_DIR goes when no row and no
    stored file has its SHA-256 and nothing in it changed within `FOLDER_GRACE`.
    Returns {"analyses": rows removed, "folders": folders removed}.
    """
    analyses, folders = _remove_analyses(now or timezone.now(), batch=batch)
    logger.info(
        "upkeep: %d analysis row(s) and %d folder(s) of files no job holds removed",
        analyses,
        folders,
    )
    return {"analyses": analyses, "folders": folders}


def _held_files() -> Q:
    """Jobs whose stored file is still there to print."""
    return Q(file_removed_at__isnull=True) & ~Q(file="") & ~Q(sha256="")


def _remove_analyses(
    now: datetime, *, only: set[str] | None = None, batch: int = BATCH_ROWS
) -> tuple[int, int]:
    held = set(
        Job.objects.filter(_held_files())
        .order_by()
        .values_list("sha256", flat=True)
        .distinct()
    )
    # A waiting farm job's analysis routes it (jobs/farm).
    held |= set(FarmJob.objects.exclude(file="").values_list("sha256", flat=True))
    rows = 0
    settled = FileAnalysis.objects.filter(state__in=_SETTLED)
    after = 0
    while True:
        page = list(
            settled.filter(pk__gt=after)
            .order_by("pk")
            .values_list("pk", "sha256")[:batch]
        )
        orphans = [
            pk
            for pk, digest in page
            if digest not in held and (only is None or digest in only)
        ]
        if orphans:
            rows += _delete_analysis_rows(orphans)
        if len(page) < batch:
            break
        after = page[-1][0]
    return rows, _remove_analysis_folders(now, held, only)


def _delete_analysis_rows(pks: list[int]) -> int:
    """Delete the rows *pks*, checked again in the deleting transaction: a file
    stored (or an analysis asked again) since they were read keeps its row."""
    holder = Job.objects.filter(_held_files(), sha256=OuterRef("sha256"))
    with transaction.atomic():
        _, by_model = (
            FileAnalysis.objects.filter(pk__in=pks, state__in=_SETTLED)
            .exclude(Exists(holder))
            .delete()
        )
    return by_model.get(FileAnalysis._meta.label, 0)


def _remove_analysis_folders(
    now: datetime, held: set[str], only: set[str] | None
) -> int:
    root = Path(settings.ANALYSIS_DIR)
    with_rows = set(
        FileAnalysis.objects.order_by().values_list("sha256", flat=True).distinct()
    )
    fresh = _ns(now - FOLDER_GRACE)
    removed = 0
    for entry in _subfolders(root):
        digest = entry.name
        if not _SHA256.match(digest) or (only is not None and digest not in only):
            continue
        if digest in held or digest in with_rows:
            continue
        if _newest_change(Path(entry.path)) >= fresh:
            continue
        # Asked again right before it goes: a file stored since the lists were read.
        if (
            FileAnalysis.objects.filter(sha256=digest).exists()
            or Job.objects.filter(_held_files(), sha256=digest).exists()
        ):
            continue
        shutil.rmtree(entry.path, ignore_errors=True)
        removed += 1
    return removed


def _newest_change(folder: Path) -> int:
    """The latest mtime (ns) of the folder and the files in it."""
    newest = folder.stat().st_mtime_ns
    for entry in _files(folder):
        newest = max(newest, entry.stat(follow_symlinks=False).st_mtime_ns)
    return newest
