"""What clients may ask of a printer: validate, write the intent to the database, return.

The printer's worker picks the rows up; nothing here touches a port.
"""

from __future__ import annotations

import os
import re
import shutil
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

from django.conf import settings
from django.db import transaction

from jobs.analysing import request_analysis
from jobs.gcode import BadGcode, FileFacts, inspect_file
from jobs.models import Job
from jobs.paths import inside
from printers.doorbell import ring_at_commit
from printers.driver import LinkConfig
from printers.worker.spool import next_position

if TYPE_CHECKING:
    from datetime import datetime

    from django.contrib.auth.models import AbstractBaseUser
    from django.core.files.uploadedfile import UploadedFile

    from printers.models import Printer

_SAFE_NAME = re.compile(r"[^A-Za-z0-9._ -]+")
#: The longest stored file name (a file system takes 255 bytes; stored names get
#: a unique prefix or suffix, farm copies `farm<id>-` too).
MAX_NAME = 180


def storage_dir(printer: Printer) -> Path:
    """The printer's job storage (`/sd/` and `/fs/` of [ESP700])."""
    path = Path(settings.JOB_STORAGE_DIR) / printer.slug
    path.mkdir(parents=True, exist_ok=True)
    return path


def stored_file(printer: Printer, name: str) -> Path:
    """The file *name* in the printer's storage (PathRefused if it would leave it)."""
    return inside(storage_dir(printer), name)


def safe_name(name: str) -> str:
    """A file name that cannot climb out of the storage folder, nor make a path
    the file system refuses: at most MAX_NAME characters (its extension kept),
    which leaves room for the prefixes that make stored names unique."""
    cleaned = _SAFE_NAME.sub("_", Path(name).name).strip(" .")
    if not cleaned:
        raise BadGcode(f"{name!r} is not a usable file name")
    if len(cleaned) > MAX_NAME:
        stem, dot, extension = cleaned.rpartition(".")
        if not dot or len(extension) > 16:
            stem, dot, extension = cleaned, "", ""
        keep = MAX_NAME - len(extension) - len(dot)
        cleaned = stem[:keep].rstrip(" .") + dot + extension
    return cleaned


def enqueue_job(
    printer: Printer,
    source: Path,
    *,
    name: str = "",
    origin: str = "",
    user: AbstractBaseUser | None = None,
    queue: bool = True,
    move: bool = False,
    sha256: str = "",
) -> Job:
    """Check *source*, copy it into the printer's storage and queue a job for it.

    1. Inspect the file (binary, empty, too-long lines -> BadGcode) before storing;
       a given *sha256* must be the file's (ChecksumMismatch), checked before the
       job exists: a queued job is a worker's to start at once.
    2. Copy it beside the other jobs under a unique name (never overwrite one).
    3. Create the job at the end of the printer's queue (or only store it when
       *queue* is false: OctoPrint's upload without print, Repetier's models).

    *move* renames *source* into the storage (an upload's temporary file) instead of
    copying it, so a large upload is written to disk once.
    """
    name = safe_name(name or source.name)
    config = LinkConfig.from_printer(printer)
    size = source.stat().st_size if source.is_file() else 0
    if size > settings.PRINTHOST_MAX_JOB_BYTES:
        raise BadGcode(
            f"{name}: {size} bytes is over the limit of "
            f"{settings.PRINTHOST_MAX_JOB_BYTES} bytes"
        )
    facts = inspect_file(
        source,
        max_command_length=config.command_limit,
        name=name,
        grbl=config.firmware == "grbl",
    )
    check_sha256(name, facts.sha256, sha256)
    target = stored_file(printer, f"{uuid.uuid4().hex[:8]}-{name}")
    if move:
        shutil.move(source, target)
    else:
        shutil.copyfile(source, target)
    state = Job.State.QUEUED if queue else Job.State.STORED
    return _create_job(printer, target, name, facts, origin, user=user, state=state)


def enqueue_upload(
    printer: Printer,
    upload: UploadedFile | BinaryIO,
    *,
    name: str,
    origin: str = "",
    user: AbstractBaseUser | None = None,
    queue: bool = True,
    sha256: str = "",
) -> Job:
    """Store an uploaded file (streamed in chunks, never whole in memory) as a job.

    A Django upload already on disk (TemporaryUploadedFile) is moved, not copied.
    *sha256*, when given, must match the stored file (Moonraker's `checksum`).
    """
    name = safe_name(name)
    staging = inside(storage_dir(printer), f".upload-{uuid.uuid4().hex}", hidden=True)
    try:
        receive_upload(upload, staging)
        job = enqueue_job(
            printer,
            staging,
            name=name,
            origin=origin,
            user=user,
            queue=queue,
            move=True,
            sha256=sha256,
        )
    finally:
        if staging.exists():
            staging.unlink()
    return job


def check_sha256(name: str, measured: str, given: str) -> None:
    """ChecksumMismatch unless *given* (a client's SHA-256; "" for none) is
    *measured*."""
    given = given.strip().lower()
    if given and given != measured:
        raise ChecksumMismatch(
            f"{name}: SHA-256 {measured} does not match the given {given}"
        )


def receive_upload(upload: UploadedFile | BinaryIO, target: Path) -> None:
    """Write *upload* to *target*: a Django upload already on disk is moved, any
    other is streamed in chunks (never whole in memory)."""
    temp_path = getattr(upload, "temporary_file_path", None)
    if temp_path is not None:
        # Move before closing: closing a TemporaryUploadedFile deletes it.
        shutil.move(temp_path(), target)
        upload.close()  # type: ignore[union-attr]
        return
    with target.open("wb") as out:
        chunks = getattr(upload, "chunks", None)
        if chunks is not None:
            for chunk in chunks():
                out.write(chunk)
        else:
            shutil.copyfileobj(upload, out, 1024 * 1024)


def enqueue_checked_file(
    printer: Printer,
    source: Path,
    *,
    name: str,
    facts: FileFacts,
    stored_as: str,
    origin: str = "",
    user: AbstractBaseUser | None = None,
) -> Job:
    """Queue a file that already passed the upload checks (a farm job's) on *printer*.

    The file is hard-linked into the printer's storage as *stored_as* (copied where
    the storage is on another file system), then the job is created at the end of
    the queue and its analysis asked for, as for any upload. A file of that name
    left by an attempt that did not commit is replaced. Call it inside the caller's
    transaction: if that rolls back, the caller removes the link.
    """
    target = stored_file(printer, safe_name(stored_as))
    target.unlink(missing_ok=True)
    try:
        os.link(source, target)
    except OSError:
        shutil.copyfile(source, target)
    return _create_job(printer, target, name, facts, origin, user=user)


class ChecksumMismatch(BadGcode):
    """The stored file's SHA-256 is not the one the client said it sent."""


def delete_job_file(job: Job) -> None:
    """Remove a job's file unless another job still uses it (reprints share files)."""
    if not job.file:  # a print from the printer's SD card has no stored file
        return
    others = Job.objects.filter(file=job.file).exclude(pk=job.pk).exists()
    if not others:
        job.path.unlink(missing_ok=True)


class FileRemoved(BadGcode):
    """The job's file was removed by the upkeep, past its printer's `job_file_days`
    (HTTP 410): the job is history and cannot be printed again."""

    def __init__(self, job: Job, removed_at: datetime) -> None:
        super().__init__(
            f"job {job.pk} ({job.name}): its file was removed on "
            f"{removed_at:%Y-%m-%d}, {job.printer.job_file_days} days after the job "
            "ended (the printer's job_file_days); upload the file again to print it"
        )


def reprint(job: Job, *, origin: str = "", user: AbstractBaseUser | None = None) -> Job:
    """Queue the same job again (its stored file, or its file on the SD card) at the
    end of the queue.

    FileRemoved when the upkeep removed the file (checked on the locked row, so a
    reprint and the upkeep's removal never both win); BadGcode when it is gone
    otherwise. Either way nothing is queued.
    """
    with transaction.atomic():
        if job.file:
            removed = (
                Job.objects.select_for_update()
                .filter(pk=job.pk)
                .values_list("file_removed_at", flat=True)
            )
            removed_at = next(iter(removed), None)
            if removed_at is not None:
                raise FileRemoved(job, removed_at)
            if not job.path.is_file():
                raise BadGcode(f"{job.name}: the stored file is gone")
        again = _copy_job(job, origin=origin, user=user)
        request_analysis(again)
    return again


def _copy_job(job: Job, *, origin: str, user: AbstractBaseUser | None) -> Job:
    return Job.objects.create(
        printer=job.printer,
        name=job.name,
        kind=job.kind,
        sd_name=job.sd_name,
        print_after=job.print_after,
        file=job.file,
        size_bytes=job.size_bytes,
        line_count=job.line_count,
        sha256=job.sha256,
        position=next_position(job.printer_id),
        origin=origin,
        uploaded_by=user,
    )


def queue_job(job: Job) -> bool:
    """Put a stored job at the end of its printer's queue; False if it was not stored."""
    queued = Job.objects.filter(pk=job.pk, state=Job.State.STORED).update(
        state=Job.State.QUEUED, position=next_position(job.printer_id)
    )
    if queued:
        ring_at_commit(job.printer_id)
    return bool(queued)


def queue_stored_file(printer: Printer, stored_name: str, *, origin: str = "") -> Job:
    """Queue a file already in the printer's storage ([ESP700]stream=/sd/...).

    The name must stay inside the storage (`stored_file`), and the file passes the
    upload checks (`check_stored_file`) before a job exists for it.
    """
    path = stored_file(printer, stored_name)
    facts = check_stored_file(printer, path, name=stored_name)
    return _create_job(printer, path, path.name, facts, origin)


def check_stored_file(printer: Printer, path: Path, *, name: str) -> FileFacts:
    """The upload checks (binary, too-long or unsendable lines) for a stored file."""
    config = LinkConfig.from_printer(printer)
    return inspect_file(
        path,
        max_command_length=config.command_limit,
        name=name,
        grbl=config.firmware == "grbl",
    )


def _create_job(
    printer: Printer,
    path: Path,
    name: str,
    facts: FileFacts,
    origin: str,
    *,
    user: AbstractBaseUser | None = None,
    state: str = Job.State.QUEUED,
) -> Job:
    relative = path.resolve().relative_to(Path(settings.JOB_STORAGE_DIR).resolve())
    with transaction.atomic():
        job = Job.objects.create(
            state=state,
            uploaded_by=user,
            printer=printer,
            name=name,
            file=str(relative),
            size_bytes=facts.size_bytes,
            line_count=facts.line_count,
            sha256=facts.sha256,
            position=next_position(printer.pk),
            origin=origin,
        )
        request_analysis(job)
    return job


def reorder_queue(printer: Printer, ids: list[int]) -> list[Job]:
    """Put the queued jobs *ids* first, in that order; the other queued jobs follow.

    Only queued jobs of *printer* may be named (ValueError otherwise). Positions are
    rewritten from the queue's lowest one upwards in one transaction, so a worker
    claiming the head meanwhile sees either the old or the new order.
    """
    if len(set(ids)) != len(ids):
        raise ValueError("a job appears twice in the new order")
    with transaction.atomic():
        queued = list(
            Job.objects.select_for_update()
            .filter(printer=printer, state=Job.State.QUEUED)
            .order_by("position", "id")
        )
        for job in queued:
            job.printer = printer  # all of them are its jobs: no query per job later
        by_id = {job.pk: job for job in queued}
        unknown = [i for i in ids if i not in by_id]
        if unknown:
            raise ValueError(
                f"not queued on {printer.slug}: {', '.join(str(i) for i in unknown)}"
            )
        order = [by_id[i] for i in ids] + [j for j in queued if j.pk not in set(ids)]
        base = min((job.position for job in queued), default=0)
        for index, job in enumerate(order):
            position = base + index
            if job.position != position:
                job.position = position
                Job.objects.filter(pk=job.pk).update(position=position)
    return order


def queue_is_empty(printer: Printer) -> bool:
    """No job waits in *printer*'s queue (Repetier's `autostart=-1` asks this)."""
    return not Job.objects.filter(printer=printer, state=Job.State.QUEUED).exists()
