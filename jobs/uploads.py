"""Uploads that arrive in pieces: the seed's create + append, and resumable sessions.

A session is an `Upload` row and a partial file in the printer's storage
(`<storage>/<slug>/.uploads/<id>.part`). Chunks are appended in order; the offset a
client must continue from is the partial file's size, read from disk every time, so
what the server says it has is exactly what it has, even after a dropped connection.
When the last byte is in, the file goes through the normal job path
(`enqueue_job(..., move=True)`: sanity check, SHA-256, a queued or stored job).

Abandoned sessions (untouched for PRINTHOST_UPLOAD_EXPIRE_HOURS) are removed with
their partial files by the upkeep (`jobs/upkeep.py`, from Celery beat), never in a
request.
"""

from __future__ import annotations

import re
import uuid
from typing import TYPE_CHECKING

from django.conf import settings
from django.utils import timezone

from jobs.gcode import BadGcode
from jobs.models import Job, Upload
from jobs.services import (
    enqueue_job,
    safe_name,
    storage_dir,
)

if TYPE_CHECKING:
    from collections.abc import Callable

    from django.contrib.auth.models import AbstractBaseUser

    from printers.models import Printer

#: How much of a request body is read and written at a time.
CHUNK = 1 << 20
_SHA256 = re.compile(r"^[0-9a-fA-F]{64}$")


class OffsetMismatch(Exception):
    """The client's offset is not where the partial file ends (HTTP 409)."""

    def __init__(self, expected: int, given: int) -> None:
        super().__init__(
            f"upload offset is {expected}, not {given}: continue from {expected}"
        )
        self.expected = expected
        self.given = given


def max_bytes() -> int:
    """The largest job file the host accepts (PRINTHOST_MAX_JOB_BYTES)."""
    return int(settings.PRINTHOST_MAX_JOB_BYTES)


def _over_limit(name: str, size: int) -> BadGcode:
    # "over the limit" is what the API maps to 413.
    return BadGcode(f"{name}: {size} bytes is over the limit of {max_bytes()} bytes")


def open_upload(
    printer: Printer,
    name: str,
    *,
    size: int = 0,
    sha256: str = "",
    user: AbstractBaseUser | None = None,
    options: dict | None = None,
) -> Upload:
    """Start a session for *name* (announced *size*, 0 = unknown) on *printer*.

    Bad names, sizes and checksums are refused here, before a byte is sent.
    """
    name = safe_name(name)
    if size < 0:
        raise BadGcode(f"{name}: size must be 0 or more, not {size}")
    if size > max_bytes():
        raise _over_limit(name, size)
    if sha256 and not _SHA256.match(sha256):
        raise BadGcode(f"{name}: sha256 must be 64 hex digits")
    upload_id = uuid.uuid4().hex
    folder = storage_dir(printer) / ".uploads"
    folder.mkdir(parents=True, exist_ok=True)
    partial = folder / f"{upload_id}.part"
    partial.touch()
    return Upload.objects.create(
        id=upload_id,
        printer=printer,
        user=user,
        name=name,
        size=size,
        sha256_expected=sha256.lower(),
        path=str(partial.relative_to(settings.JOB_STORAGE_DIR)),
        options=options or {},
    )


def offset_of(upload: Upload) -> int:
    """Bytes really on disk: where the next chunk must start."""
    try:
        return upload.partial_path.stat().st_size
    except FileNotFoundError:
        return 0


def append(
    upload: Upload,
    read: Callable[[int], bytes],
    *,
    offset: int | None = None,
    length: int | None = None,
) -> int:
    """Append what *read* yields (until it returns b"") and return the new offset.

    *offset*, when given, must equal the current one (else OffsetMismatch, nothing
    written). A chunk that would pass the announced size or the host's limit is
    refused before writing when its *length* is known, and cut off otherwise: the
    partial file never holds more than allowed. If *read* fails midway (a dropped
    connection), what arrived stays on disk and the offset says so.
    """
    current = offset_of(upload)
    if offset is not None and offset != current:
        raise OffsetMismatch(current, offset)
    cap = upload.size or max_bytes()
    if length is not None and current + length > cap:
        raise _too_big(upload, current + length)
    written = current
    with upload.partial_path.open("ab") as out:
        while True:
            chunk = read(CHUNK)
            if not chunk:
                break
            if written + len(chunk) > cap:
                out.write(chunk[: cap - written])
                out.flush()
                raise _too_big(upload, written + len(chunk))
            out.write(chunk)
            written += len(chunk)
    Upload.objects.filter(pk=upload.pk).update(updated_at=timezone.now())
    return written


def _too_big(upload: Upload, size: int) -> BadGcode:
    if upload.size and upload.size <= max_bytes():
        return BadGcode(
            f"{upload.name}: {size} bytes is over the limit of the announced size "
            f"{upload.size} bytes"
        )
    return _over_limit(upload.name, size)


def is_complete(upload: Upload) -> bool:
    """True when the announced size is reached (never for an unknown size)."""
    return bool(upload.size) and offset_of(upload) >= upload.size


def finish(upload: Upload, *, origin: str = "", queue: bool = True) -> Job:
    """Turn a complete session into a job (queued, or only stored) and end the session.

    1. The size must be the announced one (if one was announced).
    2. `enqueue_job` checks the file (binary, empty, too-long lines) and moves it into
       the printer's storage; SHA-256 is measured on the way.
    3. A given SHA-256 must match (ChecksumMismatch), checked before the job exists.
    A file that fails the checks ends the session too: its bytes cannot become a job.
    """
    have = offset_of(upload)
    if upload.size and have != upload.size:
        raise BadGcode(
            f"{upload.name}: upload incomplete, {have} of {upload.size} bytes received"
        )
    try:
        job = enqueue_job(
            upload.printer,
            upload.partial_path,
            name=upload.name,
            origin=origin,
            user=upload.user,
            queue=queue,
            move=True,
            sha256=upload.sha256_expected,
        )
    except BadGcode:  # ChecksumMismatch too: the job was never made
        discard(upload)
        raise
    Upload.objects.filter(pk=upload.pk).delete()
    return job


def discard(upload: Upload) -> None:
    """End a session and delete its partial file."""
    upload.partial_path.unlink(missing_ok=True)
    Upload.objects.filter(pk=upload.pk).delete()
