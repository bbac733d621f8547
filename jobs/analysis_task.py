"""The analysis task's body, in a Celery worker: claim, read, analyse, store.

`run(pk, worker=...)` claims the row (a conditional update: pending, or running
with a silent worker), streams the file through the analyser in chunks with a
heartbeat, stores the thumbnails and the result, and marks the row done or failed
with the reason. A row already done, or being run by a live worker, is left
alone: a task delivered twice does the work once. Asking for an analysis and
reading one are jobs/analysing.py; this module alone loads the analyser (numpy),
so a printer worker or a web process never does.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import socket
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from django.conf import settings
from django.db import DatabaseError
from django.db.models import F, Q
from django.utils import timezone

from jobs.analysing import (
    object_ranges_of,
    stale_before,
    summary_of,
    thumbnail_dir,
    toolpath_path,
)
from jobs.analysis.analyser import Analyser
from jobs.analysis.limits import Materials, MotionLimits, defaults_for
from jobs.bgcode import BadBgcode, BgcodeReader, BlockType, is_bgcode, metadata_of
from jobs.models import FarmJob, FileAnalysis, Job

if TYPE_CHECKING:
    from collections.abc import Iterator
    from typing import BinaryIO

    from jobs.analysis.result import Analysis
    from jobs.analysis.thumbnails import Thumbnail

logger = logging.getLogger("printhost.analysis")

_CHUNK = 1 << 20
#: Characters of an analysis' notes kept (`FileAnalysis.reason`).
MAX_REASON = 2000
#: Times an analysis is started before it is failed: one that stopped that often
#: without finishing (its worker killed, out of memory) would only stop again.
MAX_ATTEMPTS = 3
#: Seconds between heartbeats while a file is read.
HEARTBEAT_SECONDS = 1.0
#: Timeline marks kept at most per file (the stride grows for huge files).
MAX_MARKS = 20_000
#: Timeline marks a file gets at least (the stride shrinks from 256 commands for a
#: small file, down to one): the ETA reads the time at the acknowledged line from
#: the timeline, and a mark every 256 commands is a third of a two-minute print.
MIN_MARKS = 1024


class LostClaim(RuntimeError):
    """Another worker took the analysis over (this one was thought dead)."""


def worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def claim(pk: int, worker: str) -> bool:
    """Take the analysis for *worker*: only a pending one, or one whose worker is silent."""
    now = timezone.now()
    free = Q(state=FileAnalysis.State.PENDING) | Q(
        state=FileAnalysis.State.RUNNING, heartbeat_at__lt=stale_before()
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
    if analysis.attempts > MAX_ATTEMPTS:
        _finish(
            analysis, worker, failed=f"started {analysis.attempts - 1} times without "
            "finishing (its worker stopped: out of memory or killed?); not tried again",
        )  # fmt: skip
        return "failed"
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
    if found.objects:  # read now, not by the first viewer of the job's page
        try:
            object_ranges_of(analysis.sha256, path)
        except Exception:  # the preview reads them itself then
            logger.exception("analysis %s: object ranges of %s", pk, path.name)
    return _finish(analysis, worker, result=found)


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
            if chunk:
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
    to the analyser as a text file's header comments would. Every block yields
    (nothing to feed after the others), so the reader's heartbeats come between
    thumbnails too: a file of large pictures would otherwise look dead."""
    for block in BgcodeReader(handle, name=name, digest=digest).blocks():
        if block.type == BlockType.GCODE:
            yield block.data, block.end
            continue
        if block.type == BlockType.THUMBNAIL:
            analyser.add_picture(block.image, block.data)
        else:
            for key, value in metadata_of(block).items():
                analyser.notes.comment(
                    f"generated by {value}" if key == "Producer" else f"{key} = {value}"
                )
        yield b"", block.end


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
) -> str:
    """Store the outcome: "done", or "failed" (*failed* says why, or the result
    cannot be stored)."""
    now = timezone.now()
    changes: dict[str, Any] = {"finished_at": now, "heartbeat_at": now}
    found = summary = None
    if result is not None:
        found, summary = result.as_dict(), summary_of(result)
        try:  # what the database's JSON takes: an inf or a NaN would fail the row
            json.dumps([found, summary], allow_nan=False)
        except ValueError:
            failed = "the file holds a number too large to work with (inf or NaN)"
            found = None
    if found is None:
        changes.update(state=FileAnalysis.State.FAILED, reason=failed)
    else:
        # The same note once each: a file can make the analyser say one thousands
        # of times, and the reason goes out with every job of the file.
        notes = "; ".join(dict.fromkeys(result.notes))  # type: ignore[union-attr]
        changes.update(
            state=FileAnalysis.State.DONE,
            result=found,
            summary=summary,
            reason=notes[:MAX_REASON],
        )
    FileAnalysis.objects.filter(pk=analysis.pk, worker=worker).update(**changes)
    logger.info(
        "analysis %s of %s: %s %s",
        analysis.pk,
        analysis.sha256[:12],
        changes["state"],
        changes["reason"],
    )
    return "failed" if found is None else "done"


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
