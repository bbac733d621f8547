"""Farm jobs from their upload to their end in the queue: store, analyse, change, cancel.

A farm upload is stored once, in the job storage's `farm/` folder (`farm` is a
reserved printer slug, so no printer's storage is that folder), after the checks
every upload gets (`jobs.services`: a usable name, the size limit, `inspect_file`:
text or binary G-code, no unsendable line). Its analysis is asked for in the same
transaction, with the default Marlin profile: the bounding box the matcher needs
does not depend on a printer's motion limits, and printers on the default profile
share the row. The printer's job made at the claim asks for its own printer's
analysis, as every job does.
"""

from __future__ import annotations

import logging
import uuid
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO

from django.conf import settings
from django.db import transaction
from django.utils import timezone
from django.utils.dateparse import parse_datetime

from jobs.analysing import profile_of, send
from jobs.farm.models import FarmJob
from jobs.farm.requirements import BadRequirement, Requirements, parse_requirements
from jobs.gcode import BadGcode, inspect_file
from jobs.models import FileAnalysis
from jobs.paths import inside
from jobs.services import check_sha256, receive_upload, safe_name
from printers.models import Printer

if TYPE_CHECKING:
    from collections.abc import Mapping

    from django.contrib.auth.models import AbstractBaseUser
    from django.core.files.uploadedfile import UploadedFile

logger = logging.getLogger("printhost.farm")

#: The farm's folder in the job storage (the reserved printer slug).
FARM_FOLDER = "farm"
#: Priorities run from -1000 to 1000; 0 is the default.
PRIORITY_LIMIT = 1000
#: A deadline's year (UTC) lies in this range: one PostgreSQL stores but cannot
#: read back (before the year 1 or after 9999 in UTC) would break the queue's reads.
DEADLINE_YEARS = (2000, 2200)
#: What a job waiting for its analysis says.
WAITING_FOR_ANALYSIS = "waiting for the file's analysis"


def farm_dir() -> Path:
    """The farm's folder under the job storage (made on first use)."""
    path = Path(settings.JOB_STORAGE_DIR) / FARM_FOLDER
    path.mkdir(parents=True, exist_ok=True)
    return path


def parse_priority(value: object) -> int:
    """An integer from -1000 to 1000 (higher goes first); 0 when not given."""
    if value in (None, ""):
        return 0
    if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
        raise BadRequirement(f"priority must be a whole number, not {value!r}")
    try:
        number = int(value)  # type: ignore[call-overload]
    except (TypeError, ValueError):
        raise BadRequirement(
            f"priority must be a whole number, not {value!r}"
        ) from None
    if abs(number) > PRIORITY_LIMIT:
        raise BadRequirement(
            f"priority must be between -{PRIORITY_LIMIT} and {PRIORITY_LIMIT}, "
            f"not {number}"
        )
    return number


def parse_deadline(value: object) -> datetime | None:
    """An ISO 8601 time (UTC when it names no zone), or None when not given."""
    if value in (None, ""):
        return None
    if not isinstance(value, str):
        raise BadRequirement(f"deadline must be an ISO 8601 time, not {value!r}")
    try:
        when = parse_datetime(value.strip())
    except ValueError:
        when = None
    if when is None:
        raise BadRequirement(
            f"deadline must be an ISO 8601 time such as 2026-05-01T18:00:00Z, "
            f"not {value!r}"
        )
    if timezone.is_naive(when):
        when = when.replace(tzinfo=UTC)
    try:
        utc = when.astimezone(UTC)
    except OverflowError:  # 0001-01-01T00:00+14:00 is before the year 1 in UTC
        utc = None
    if utc is None or not DEADLINE_YEARS[0] <= utc.year <= DEADLINE_YEARS[1]:
        # The database could store it, and then not read it back (PostgreSQL).
        raise BadRequirement(
            f"deadline must fall in the years {DEADLINE_YEARS[0]} to "
            f"{DEADLINE_YEARS[1]}, not {value!r}"
        )
    return utc


def store_farm_upload(
    upload: UploadedFile | BinaryIO,
    *,
    name: str,
    requirements: Requirements,
    priority: int = 0,
    deadline: datetime | None = None,
    origin: str = "",
    user: AbstractBaseUser | None = None,
    sha256: str = "",
) -> FarmJob:
    """Check and store an upload for the farm queue, and ask for its analysis.

    1. A usable name; the bytes staged in the farm folder (moved when the upload
       is already on disk).
    2. The size limit, `inspect_file` and the client's *sha256* if it gave one
       (BadGcode, ChecksumMismatch: nothing is kept, no dispatcher sees a job).
    3. The file under a unique name, the farm job and its analysis request in one
       transaction; the task goes to Celery once it commits.
    """
    name = safe_name(name)
    folder = farm_dir()
    staging = inside(folder, f".upload-{uuid.uuid4().hex}", hidden=True)
    target = inside(folder, f"{uuid.uuid4().hex[:8]}-{name}")
    try:
        receive_upload(upload, staging)
        size = staging.stat().st_size
        if size > settings.PRINTHOST_MAX_JOB_BYTES:
            raise BadGcode(
                f"{name}: {size} bytes is over the limit of "
                f"{settings.PRINTHOST_MAX_JOB_BYTES} bytes"
            )
        facts = inspect_file(staging, name=name)
        check_sha256(name, facts.sha256, sha256)
        staging.replace(target)
        with transaction.atomic():
            farm_job = FarmJob.objects.create(
                name=name,
                file=str(target.relative_to(Path(settings.JOB_STORAGE_DIR).resolve())),
                size_bytes=facts.size_bytes,
                line_count=facts.line_count,
                sha256=facts.sha256,
                longest_command=facts.longest,
                material=requirements.material,
                colour=requirements.colour,
                nozzle_diameter=requirements.nozzle,
                profile=requirements.profile,
                tags=list(requirements.tags),
                priority=priority,
                deadline=deadline,
                reason=WAITING_FOR_ANALYSIS,
                origin=origin,
                uploaded_by=user,
            )
            request_farm_analysis(farm_job)
    except BaseException:
        staging.unlink(missing_ok=True)
        if not FarmJob.objects.filter(file__endswith=target.name).exists():
            target.unlink(missing_ok=True)
        raise
    return farm_job


def request_farm_analysis(farm_job: FarmJob) -> FileAnalysis:
    """Link *farm_job* to its file's analysis on the default Marlin profile, asking
    Celery for it if the row is new (`jobs.analysing.request_analysis`'s way)."""
    digest, chosen = profile_of(Printer(firmware=Printer.Firmware.MARLIN))
    analysis, created = FileAnalysis.objects.get_or_create(
        sha256=farm_job.sha256,
        profile=digest,
        defaults={"firmware": Printer.Firmware.MARLIN, "settings": chosen},
    )
    FarmJob.objects.filter(pk=farm_job.pk).update(analysis=analysis)
    farm_job.analysis = analysis
    if created:
        pk = analysis.pk
        transaction.on_commit(lambda: send(pk))
    return analysis


class NotWaiting(Exception):
    """The farm job was already given to a printer or cancelled (HTTP 409)."""

    def __init__(self, farm_job: FarmJob) -> None:
        farm_job.refresh_from_db()
        if farm_job.state == FarmJob.State.ASSIGNED:
            where = farm_job.printer.slug if farm_job.printer else "a printer"
            text = (
                f"farm job {farm_job.pk} was already given to {where} (job "
                f"{farm_job.job_id}): act on that job instead"
            )
        else:
            text = f"farm job {farm_job.pk} is {farm_job.state}"
        super().__init__(text)


def cancel(farm_job: FarmJob) -> None:
    """Take a waiting job out of the queue and remove its file (NotWaiting if the
    dispatcher gave it to a printer first: the conditional update decides)."""
    done = FarmJob.objects.filter(pk=farm_job.pk, state=FarmJob.State.WAITING).update(
        state=FarmJob.State.CANCELLED, cancelled_at=timezone.now(), reason=""
    )
    if not done:
        raise NotWaiting(farm_job)
    farm_job.refresh_from_db()
    remove_file(farm_job)


def remove_file(farm_job: FarmJob) -> None:
    """Remove the farm's copy of the file (the printer's job keeps its own link)."""
    if not farm_job.file:
        return
    try:
        farm_job.path.unlink(missing_ok=True)
    except BadGcode:
        logger.warning("farm job %s names a file outside the storage", farm_job.pk)
    FarmJob.objects.filter(pk=farm_job.pk).update(file="")
    farm_job.file = ""


def change(farm_job: FarmJob, changes: Mapping[str, Any]) -> FarmJob:
    """Change a waiting job's priority, deadline or requirements.

    *changes*: `priority`, `deadline` (null removes it), and requirement fields
    (`material`, `colour`, `nozzle`, `profile`, `tags`; each replaces the old one,
    "" or null clears it). Every value is checked before anything is written
    (BadRequirement), and the update is conditional on the job still waiting
    (NotWaiting): the dispatcher may have just given it away.
    """
    known = {"priority", "deadline", "material", "colour", "color", "nozzle"}
    known |= {"nozzle_diameter", "profile", "tags"}
    unknown = sorted(set(changes) - known)
    if unknown:
        raise BadRequirement(
            f"cannot change {', '.join(unknown)}: a farm job's priority, deadline, "
            "material, colour, nozzle, profile and tags can be changed"
        )
    if not changes:
        raise BadRequirement(
            "nothing to change: send priority, deadline or requirements"
        )
    fields: dict[str, Any] = {}
    if "priority" in changes:
        fields["priority"] = parse_priority(changes["priority"])
    if "deadline" in changes:
        fields["deadline"] = parse_deadline(changes["deadline"])
    current = farm_job.requirements.as_dict()
    current["nozzle"] = current.pop("nozzle_diameter")
    merged = {**current, **{k: v for k, v in changes.items() if k not in fields}}
    if "color" in changes:
        merged["colour"] = changes["color"]
    if "nozzle_diameter" in changes:
        merged["nozzle"] = changes["nozzle_diameter"]
    merged = {k: "" if v is None else v for k, v in merged.items()}
    wanted = parse_requirements(merged)
    fields.update(
        material=wanted.material,
        colour=wanted.colour,
        nozzle_diameter=wanted.nozzle,
        profile=wanted.profile,
        tags=list(wanted.tags),
    )
    done = FarmJob.objects.filter(pk=farm_job.pk, state=FarmJob.State.WAITING).update(
        **fields
    )
    if not done:
        raise NotWaiting(farm_job)
    farm_job.refresh_from_db()
    return farm_job
