"""Analysis of stored job files: asking for it, and finding what it found.

- `request_analysis(job)`: on every stored file (any upload path, a reprint). It
  finds or creates the `FileAnalysis` row for the file's SHA-256 and the printer's
  motion profile and, for a new row, hands a task to Celery once the transaction
  commits. Nothing is analysed in the request.
- the task's body, `run(pk)`, is jobs/analysis_task.py (it alone loads the
  analyser and numpy).
- `sweep()`: sends again what a dead worker or a lost message left behind (at
  Celery worker start and from beat).
"""

from __future__ import annotations

import hashlib
import json
import logging
import uuid
from datetime import timedelta
from pathlib import Path
from typing import TYPE_CHECKING, Any

from django.conf import settings
from django.db import transaction
from django.db.models import Q
from django.utils import timezone

from jobs.analysis.limits import BadProfile, MotionLimits, defaults_for
from jobs.analysis.result import Analysis
from jobs.models import FileAnalysis, Job

if TYPE_CHECKING:
    from printers.models import Printer

logger = logging.getLogger("printhost.analysis")

#: A pending row whose message may be lost is sent again after this long (s).
RESEND_PENDING_SECONDS = 3600.0


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


def stale_before() -> Any:
    """A running analysis whose heartbeat is older than this has a dead worker."""
    return timezone.now() - timedelta(seconds=settings.PRINTHOST_ANALYSIS_STALE_SECONDS)


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


def object_ranges_of(sha256: str, path: Path) -> dict[str, list[list[int]]]:
    """Each object's command ranges in the file *path* (its SHA-256 *sha256*),
    for the preview: read once, then kept beside the file's thumbnails (the
    analysis task reads them first; a job page opened before asks for them).

    Reading a large file takes seconds: every viewer opening the job's page would
    pay them again, and could be made to.
    """
    from printers.streaming.object_places import object_ranges
    from printers.worker.spool import file_entries

    kept = thumbnail_dir(sha256) / "object-ranges.json"
    try:
        return json.loads(kept.read_text())
    except (OSError, ValueError):
        pass
    ranges = object_ranges(file_entries(path, start_index=0, start_offset=0))
    kept.parent.mkdir(parents=True, exist_ok=True)
    part = kept.with_name(f".object-ranges-{uuid.uuid4().hex}.part")
    part.write_text(json.dumps(ranges))
    part.replace(kept)
    return ranges


def toolpath_path(sha256: str, kind: str) -> Path:
    """The preview's geometry of a file (toolpath.py's records), per kind of machine."""
    if kind not in ("fff", "cnc"):
        raise ValueError(f"{kind!r} is not a kind of analysis")
    return thumbnail_dir(sha256) / f"toolpath-{kind}.bin"


def sweep() -> int:
    """Send again what a dead worker or a lost message left; returns how many."""
    stale = FileAnalysis.objects.filter(
        state=FileAnalysis.State.RUNNING, heartbeat_at__lt=stale_before()
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
