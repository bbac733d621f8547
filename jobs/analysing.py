"""Analysis of stored job files: asking for it, running it, finding what it found.

- `request_analysis(job)`: on every stored file (any upload path, a reprint). It
  finds or creates the `FileAnalysis` row for the file's SHA-256 and the printer's
  motion profile and, for a new row, hands a task to Celery once the transaction
  commits. Nothing is analysed in the request.
- `run(pk, worker=...)`: the task's body, in a Celery worker. It claims the row
  (a conditional update: pending, or running with a silent worker), streams the
  file through the analyser in chunks with a heartbeat, stores the thumbnails and
  the result, and marks the row done or failed with the reason. A row already
  done, or being run by a live worker, is left alone: a task delivered twice
  does the work once.
- `sweep()`: sends again what a dead worker or a lost message left behind (at
  Celery worker start and from beat).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import socket
import time
from datetime import timedelta
from pathlib import Path
from typing import TYPE_CHECKING, Any

from django.conf import settings
from django.db import DatabaseError, transaction
from django.db.models import F, Q
from django.utils import timezone

from jobs.analysis.analyser import Analyser
from jobs.analysis.limits import BadProfile, Materials, MotionLimits, defaults_for
from jobs.analysis.result import Analysis
from jobs.bgcode import BadBgcode, BgcodeReader, BlockType, is_bgcode, metadata_of
from jobs.models import FarmJob, FileAnalysis, Job

if TYPE_CHECKING:
    from collections.abc import Iterator
    from typing import BinaryIO

    from jobs.analysis.thumbnails import Thumbnail
    from printers.models import Printer

logger = logging.getLogger("printhost.analysis")

_CHUNK = 1 << 20
#: Seconds between heartbeats while a file is read.
HEARTBEAT_SECONDS = 1.0
#: Timeline marks kept at most per file (the stride grows for huge files).
MAX_MARKS = 20_000
#: Timeline marks a file gets at least (the stride shrinks from 256 commands for a
#: small file, down to one): the ETA reads the time at the acknowledged line from
#: the timeline, and a mark every 256 commands is a third of a two-minute print.
MIN_MARKS = 1024
#: A pending row whose message may be lost is sent again after this long (s).
RESEND_PENDING_SECONDS = 3600.0


class LostClaim(RuntimeError):
    """Another worker took the analysis over (this one was thought dead)."""


def worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def profile_of(printer: Printer) -> tuple[str, dict[str, Any]]:
    """The digest and settings an analysis for *printer* starts from.

    A stored profile the analyser cannot read (edited around the form's check)
    falls back to the firmware's defaults; the settings say so.
    """
    base = defaults_for(printer.firmware)
    note = ""
    try:
        limits = MotionLimits.from_profile(printer.motion_profile or {}, base=base)
    except BadProfile as error:
        limits, note = base, f"the printer's motion profile was ignored: {error}"
    chosen = {
        "firmware": printer.firmware,
        "limits": limits.as_profile(),
        "filament_diameter": printer.filament_diameter,
        "filament_density": printer.filament_density,
    }
    digest = hashlib.sha256(json.dumps(chosen, sort_keys=True).encode()).hexdigest()
    if note:
        chosen["note"] = note
    return digest[:16], chosen


def request_analysis(job: Job) -> FileAnalysis | None:
    """Link *job* to its file's analysis, asking Celery for it if it is new."""
    if not job.file or not job.sha256:
        return None  # a print from the printer's SD card: no file here
    digest, chosen = profile_of(job.printer)
    analysis, created = FileAnalysis.objects.get_or_create(
        sha256=job.sha256,
        profile=digest,
        defaults={"firmware": job.printer.firmware, "settings": chosen},
    )
    Job.objects.filter(pk=job.pk).update(analysis=analysis)
    job.analysis = analysis
    if created:
        pk = analysis.pk
        transaction.on_commit(lambda: send(pk))
    return analysis


def send(pk: int) -> bool:
    """Hand the analysis to the broker; a broker that is away is retried by the sweep."""
    from jobs.tasks import analyse_file

    try:
        analyse_file.delay(pk)
    except Exception as error:  # any broker failure: the sweep sends it later
        logger.warning("analysis %s not sent (%s); the sweep will send it", pk, error)
        return False
    FileAnalysis.objects.filter(pk=pk).update(sent_at=timezone.now())
    return True


def _stale_before() -> Any:
    return timezone.now() - timedelta(seconds=settings.PRINTHOST_ANALYSIS_STALE_SECONDS)


def claim(pk: int, worker: str) -> bool:
    """Take the analysis for *worker*: only a pending one, or one whose worker is silent."""
    now = timezone.now()
    free = Q(state=FileAnalysis.State.PENDING) | Q(
        state=FileAnalysis.State.RUNNING, heartbeat_at__lt=_stale_before()
    )
    taken = FileAnalysis.objects.filter(free, pk=pk).update(
        state=FileAnalysis.State.RUNNING,
        worker=worker,
        started_at=now,
        heartbeat_at=now,
        attempts=F("attempts") + 1,
        bytes_done=0,
    )
    return bool(taken)


def run(pk: int, *, worker: str | None = None) -> str:
    """Analyse one file if nobody else is: "done", "failed" or "skipped"."""
    worker = worker or worker_name()
    if not claim(pk, worker):
        return "skipped"
    analysis = FileAnalysis.objects.get(pk=pk)
    path = stored_file(analysis)
    if path is None:
        _finish(analysis, worker, failed="no stored file has this SHA-256 any more")
        return "failed"
    try:
        found, pictures = _analyse(analysis, path, worker)
    except LostClaim:
        logger.warning("analysis %s was taken over by another worker", pk)
        return "skipped"
    except DatabaseError:
        # Transient: give the row back and let the task's retry run it again.
        _release(pk, worker)
        raise
    except BadBgcode as error:  # broken on disk since its upload check
        logger.warning("analysis %s: %s", pk, error)
        _finish(analysis, worker, failed=str(error))
        return "failed"
    except Exception as error:  # no file may crash the worker
        logger.exception("analysis %s of %s failed", pk, path.name)
        _finish(analysis, worker, failed=f"{type(error).__name__}: {error}")
        return "failed"
    found.thumbnails = save_thumbnails(analysis.sha256, pictures)
    _finish(analysis, worker, result=found)
    return "done"


def _release(pk: int, worker: str) -> None:
    # The database may be away: then the claim goes stale and the sweep resends.
    with contextlib.suppress(DatabaseError):
        FileAnalysis.objects.filter(pk=pk, worker=worker).update(
            state=FileAnalysis.State.PENDING, worker=""
        )


def stored_file(analysis: FileAnalysis) -> Path | None:
    """A stored file with the analysis's SHA-256 (any job that holds it)."""
    files = [
        *Job.objects.filter(sha256=analysis.sha256)
        .exclude(file="")
        .values_list("file", flat=True)
        .distinct(),
        # A farm job's file waits in the farm folder until a printer takes it.
        *FarmJob.objects.filter(sha256=analysis.sha256)
        .exclude(file="")
        .values_list("file", flat=True),
    ]
    root = Path(settings.JOB_STORAGE_DIR)
    for name in files:
        try:
            job = Job(file=name)
            path = job.path
        except ValueError:
            continue
        if path.is_file() and path.is_relative_to(root.resolve()):
            return path
    return None


def _analyse(
    analysis: FileAnalysis, path: Path, worker: str
) -> tuple[Analysis, list[Thumbnail]]:
    chosen = analysis.settings
    limits = MotionLimits.from_profile(
        chosen.get("limits"), base=defaults_for(analysis.firmware)
    )
    materials = Materials(
        diameter=chosen.get("filament_diameter", 1.75),
        density=chosen.get("filament_density", 1.24),
    )
    commands = (
        Job.objects.filter(sha256=analysis.sha256)
        .values_list("line_count", flat=True)
        .first()
        or FarmJob.objects.filter(sha256=analysis.sha256)
        .values_list("line_count", flat=True)
        .first()
        or 0
    )
    stride = 256
    while stride > 1 and commands // stride < MIN_MARKS:
        stride //= 2
    while commands // stride > MAX_MARKS:
        stride *= 2
    folder = thumbnail_dir(analysis.sha256)
    folder.mkdir(parents=True, exist_ok=True)
    drawing = folder / f".toolpath-{analysis.pk}-{os.getpid()}.part"
    try:
        with drawing.open("wb") as sink:
            analyser = Analyser(
                limits, firmware=analysis.firmware, materials=materials,
                stride=stride, toolpath=sink,
            )  # fmt: skip
            _read(analysis, path, worker, analyser)
            found = analyser.finish()
        drawing.replace(toolpath_path(analysis.sha256, found.kind))
    finally:
        drawing.unlink(missing_ok=True)
    if chosen.get("note"):
        found.notes.append(chosen["note"])
    return found, analyser.pictures


def _read(analysis: FileAnalysis, path: Path, worker: str, analyser: Analyser) -> None:
    """Feed the stored file to *analyser*, checking its SHA-256, with heartbeats."""
    digest = hashlib.sha256()
    beat = time.monotonic()
    with path.open("rb") as handle:
        binary = is_bgcode(handle.read(4))
        handle.seek(0)
        chunks = (
            _bgcode_chunks(handle, analyser, digest, path.name)
            if binary
            else _chunks(handle, digest)
        )
        for chunk, done in chunks:
            analyser.feed(chunk)
            if time.monotonic() - beat >= HEARTBEAT_SECONDS:
                beat = time.monotonic()
                _heartbeat(analysis.pk, worker, done)
    if digest.hexdigest() != analysis.sha256:
        raise ValueError("the stored file changed since it was uploaded")


def _chunks(handle: BinaryIO, digest: Any) -> Iterator[tuple[bytes, int]]:
    """A text file's bytes in chunks, with how far into the file each ends."""
    done = 0
    while chunk := handle.read(_CHUNK):
        digest.update(chunk)
        done += len(chunk)
        yield chunk, done


def _bgcode_chunks(
    handle: BinaryIO, analyser: Analyser, digest: Any, name: str
) -> Iterator[tuple[bytes, int]]:
    """A binary G-code file's G-code, block by block; its metadata and thumbnails go
    to the analyser as a text file's header comments would."""
    for block in BgcodeReader(handle, name=name, digest=digest).blocks():
        if block.type == BlockType.GCODE:
            yield block.data, block.end
        elif block.type == BlockType.THUMBNAIL:
            analyser.add_picture(block.image, block.data)
        else:
            for key, value in metadata_of(block).items():
                analyser.notes.comment(
                    f"generated by {value}" if key == "Producer" else f"{key} = {value}"
                )


def _heartbeat(pk: int, worker: str, done: int) -> None:
    alive = FileAnalysis.objects.filter(
        pk=pk, worker=worker, state=FileAnalysis.State.RUNNING
    ).update(heartbeat_at=timezone.now(), bytes_done=done)
    if not alive:
        raise LostClaim(pk)


def _finish(
    analysis: FileAnalysis,
    worker: str,
    *,
    result: Analysis | None = None,
    failed: str = "",
) -> None:
    now = timezone.now()
    changes: dict[str, Any] = {"finished_at": now, "heartbeat_at": now}
    if result is None:
        changes.update(state=FileAnalysis.State.FAILED, reason=failed)
    else:
        changes.update(
            state=FileAnalysis.State.DONE,
            result=result.as_dict(),
            summary=summary_of(result),
            reason="; ".join(result.notes),
        )
    FileAnalysis.objects.filter(pk=analysis.pk, worker=worker).update(**changes)
    logger.info(
        "analysis %s of %s: %s %s",
        analysis.pk,
        analysis.sha256[:12],
        changes["state"],
        changes["reason"],
    )


def summary_of(result: Analysis) -> dict[str, Any]:
    """The figures a job list, a card or a slicer app shows."""
    notes = result.slicer
    heights = [layer.z for layer in result.layers]
    return {
        "kind": result.kind,
        "estimated_seconds": round(result.total_seconds, 1),
        "motion_seconds": round(result.motion_seconds, 1),
        "heating_seconds": round(result.heating_seconds, 1),
        "filament_mm": result.filament_mm,
        "filament_total": round(result.filament_total, 1),
        "filament_volume_mm3": result.filament_volume_mm3,
        "filament_weight_g": result.filament_weight_g,
        "layers": len(result.layers),
        "layer_height": notes.get("layer_height")
        or (round(heights[1] - heights[0], 3) if len(heights) > 1 else None),
        "first_layer_height": heights[0] if heights else None,
        "object_height": max(heights) if heights else notes.get("object_height"),
        "bbox": result.bbox,
        "objects": result.objects,
        "slicer": notes.get("slicer", ""),
        "slicer_version": notes.get("slicer_version", ""),
        "slicer_estimated_seconds": notes.get("estimated_seconds"),
        "material": notes.get("material", ""),
        "nozzle_diameter": notes.get("nozzle_diameter"),
        "printer_model": notes.get("printer_model", ""),
        "tools": result.tools,
        "spindle_max": result.spindle_max,
        "thumbnails": result.thumbnails,
    }


def thumbnail_dir(sha256: str) -> Path:
    if len(sha256) != 64 or any(c not in "0123456789abcdef" for c in sha256):
        raise ValueError(f"{sha256!r} is not a SHA-256")
    return Path(settings.ANALYSIS_DIR) / sha256


def toolpath_path(sha256: str, kind: str) -> Path:
    """The preview's geometry of a file (toolpath.py's records), per kind of machine."""
    if kind not in ("fff", "cnc"):
        raise ValueError(f"{kind!r} is not a kind of analysis")
    return thumbnail_dir(sha256) / f"toolpath-{kind}.bin"


def save_thumbnails(sha256: str, pictures: list[Thumbnail]) -> list[dict[str, Any]]:
    """Store each picture once per file; the list describes them (largest first)."""
    folder = thumbnail_dir(sha256)
    out: list[dict[str, Any]] = []
    seen: set[str] = set()
    for picture in sorted(pictures, key=lambda p: p.width * p.height, reverse=True):
        name = f"{picture.width}x{picture.height}.{picture.format}"
        if name in seen:
            continue
        seen.add(name)
        folder.mkdir(parents=True, exist_ok=True)
        temporary = folder / f".{name}.part"
        temporary.write_bytes(picture.data)
        temporary.replace(folder / name)
        out.append(
            {
                "name": name,
                "width": picture.width,
                "height": picture.height,
                "format": picture.format,
                "size": len(picture.data),
            }
        )
    return out


def sweep() -> int:
    """Send again what a dead worker or a lost message left; returns how many."""
    stale = FileAnalysis.objects.filter(
        state=FileAnalysis.State.RUNNING, heartbeat_at__lt=_stale_before()
    ).values_list("pk", flat=True)
    lost = (
        FileAnalysis.objects.filter(state=FileAnalysis.State.PENDING)
        .filter(
            Q(sent_at__isnull=True)
            | Q(sent_at__lt=timezone.now() - timedelta(seconds=RESEND_PENDING_SECONDS))
        )
        .values_list("pk", flat=True)
    )
    again = sorted(set(stale) | set(lost))
    for pk in again:
        send(pk)
    if again:
        logger.info("analysis sweep sent %d again: %s", len(again), again)
    return len(again)


#: Finished analyses already read, by (row, when it finished): a running job's ETA
#: is asked for on every progress write, and a big file's result is megabytes.
_PARSED: dict[tuple[int, Any], Analysis] = {}
_PARSED_KEPT = 8


def analysis_of(job: Job) -> Analysis | None:
    """The finished analysis of *job*'s file, or None (read once per process: the
    result column is loaded only when this process has not read it yet)."""
    row = job.analysis
    if row is None or row.state != FileAnalysis.State.DONE:
        return None
    key = (row.pk, row.finished_at)
    found = _PARSED.get(key)
    if found is None:
        if not row.result:
            return None
        found = Analysis.from_dict(row.result)
        if len(_PARSED) >= _PARSED_KEPT:
            _PARSED.pop(next(iter(_PARSED)))
        _PARSED[key] = found
    return found
