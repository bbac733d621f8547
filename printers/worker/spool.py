"""The stream queue's database side: claiming jobs, saving progress, recording outcomes."""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING, TypeVar

from django.db.models import F

from jobs import history, hostcache
from jobs.gcode import command_of, read_entries
from jobs.models import ACTIVE_STATES, Job
from printers import broadcast
from printers.dbclock import shared_now
from printers.reaper import LAST_SAVED
from printers.streaming import Line, Stream, StreamType
from printers.streaming.objects import ObjectFilter, ObjectMark, object_mark

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

    from printers.worker.journal import Entry

T = TypeVar("T")

_OUTCOME_STATE = {
    "completed": Job.State.COMPLETED,
    "aborted": Job.State.ABORTED,
    "failed": Job.State.FAILED,
    "interrupted": Job.State.INTERRUPTED,
}


def recover_interrupted(printer_id: int, journaled: Entry | None = None) -> list[Job]:
    """Mark jobs a dead worker left printing as INTERRUPTED, at their last acked line.

    The journal's entry (written on every ack batch) wins over the database's
    progress (saved once a second). They are never restarted by themselves: a
    half-printed part is on the bed. A job the control plane already marked
    interrupted when this host fell silent (`printers.reaper`) gets its exact
    line from the journal here.
    """
    jobs = list(Job.objects.filter(printer_id=printer_id, state__in=ACTIVE_STATES))
    for job in [*jobs, *_reaped(printer_id)]:
        progress: dict[str, int] = {}
        if journaled is not None and journaled.job_id == job.pk:
            job.lines_acked = journaled.acked
            progress = {
                "lines_acked": journaled.acked,
                "lines_sent": journaled.sent,
                "bytes_acked": journaled.bytes_acked,
            }
        job.message = _interrupted(job)
        Job.objects.filter(pk=job.pk, state__in=[*ACTIVE_STATES, job.state]).update(
            state=Job.State.INTERRUPTED,
            message=job.message,
            finished_at=job.finished_at or shared_now(),
            **progress,
        )
        history.record_run(job.pk)
        broadcast.publisher().job(job.pk)
        if job not in jobs:
            jobs.append(job)
    return jobs


def _reaped(printer_id: int) -> list[Job]:
    """Runs the control plane marked interrupted when this printer's worker fell
    silent (`printers.reaper`), not yet seen by a worker of this printer."""
    return list(
        Job.objects.filter(
            printer_id=printer_id,
            state=Job.State.INTERRUPTED,
            message__contains=LAST_SAVED,
        )
    )


def _interrupted(job: Job) -> str:
    if job.kind == Job.Kind.SD_PRINT:
        return (
            f"interrupted: the worker stopped while the printer printed {job.sd_name} "
            "from its SD card; reconnecting usually resets the printer, so check it"
        )
    if job.kind == Job.Kind.SD_UPLOAD:
        return (
            f"interrupted: the worker stopped while copying to {job.sd_name} on the "
            "SD card; the file there is incomplete: copy it again"
        )
    return (
        f"interrupted: the worker stopped at line {job.lines_acked} of "
        f"{job.line_count}; not restarted (resume it from there, or clear the bed "
        "and print it again)"
    )


def claim_next(printer_id: int) -> Job | None:
    """Take the first queued job of the printer (healthchecks' conditional UPDATE).

    On a worker host the first job waits (None) until its file has arrived from
    the control plane and its SHA-256 checks out (`jobs.hostcache`).
    """
    for job in Job.objects.filter(printer_id=printer_id, state=Job.State.QUEUED)[:5]:
        if not _file_here(job):
            return None
        won = Job.objects.filter(pk=job.pk, state=Job.State.QUEUED).update(
            state=Job.State.PRINTING,
            started_at=shared_now(),
            progress_at=None,
            message="",
        )
        if won == 1:
            job.refresh_from_db()
            broadcast.publisher().job(job.pk)
            return job
    return None


def is_job(stream: Stream) -> bool:
    """A stream that prints a job's file (not a script, a command or an SD print's
    control): its progress and outcome belong to the job's row."""
    return stream.type.is_stream and isinstance(stream.ref, int)


def _file_here(job: Job) -> bool:
    if job.kind == Job.Kind.SD_PRINT or not hostcache.on_worker_host():
        return True
    return hostcache.verified(job.sha256) is not None


def stream_for(job: Job) -> Stream:
    """The file stream that prints *job*: its commands read lazily from disk.

    A resumed run sends its preamble first, then the file from `start_line`; the
    preamble's lines stand just before the start line (index `start_line - 1`), so
    the run's progress is the file's from the first ack on.
    """
    start = job.start_line
    preamble = [
        Line(start - 1, text, job.start_offset) for text in _commands(job.preamble)
    ]
    file = file_entries(job.path, start_index=start, start_offset=job.start_offset)
    # The stream reads through the object filter: the worker finds it there
    # (`stream.lines`) to cancel an object mid-print (printers/streaming/objects.py).
    objects = ObjectFilter(
        itertools.chain(preamble, file),
        cancelled=job.cancelled_objects or (),
        place=job.start_objects or None,
    )
    stream = Stream(
        StreamType.SD_FILE_STREAM,
        objects,
        name=job.name,
        ref=job.pk,
        origin=job.origin,
    )
    stream.done = stream.reached = start
    stream.bytes_acked = job.start_offset
    return stream


def file_entries(
    path: Path, *, start_index: int, start_offset: int
) -> Iterator[Line | ObjectMark]:
    """The file's commands as Lines, and its object marker comments (which the
    commands leave out) as ObjectMarks. Only lines that send nothing are looked at
    for a marker, with one bytes search each, so the stream reads as fast as before.
    """
    entries = read_entries(
        path,
        start_index=start_index,
        start_offset=start_offset,
        comment=object_mark,
        command=Line,
    )
    return read_ahead(entries, READ_AHEAD)


#: Entries read from the file at a time (`read_ahead`).
READ_AHEAD = 32


def read_ahead(entries: Iterator[T], size: int) -> Iterator[T]:
    """*entries*, read *size* at a time, each batch in one go.

    The loop takes one line a turn, and each turn finds the code that reads and
    cleans a line gone from the processor's caches: read in batches, that code
    runs warm for all but the first line of each (in bench.streaming's long
    ping-pong case, the stream host's share of a turn fell from 45-49 to 37-38 us
    a line). Nothing decided later depends on when a line was read (the object
    filter, which does, reads from this one line at a time); an error in the file
    still comes after every line before it.
    """

    def batches() -> Iterator[list[T]]:
        while True:
            batch: list[T] = []
            try:
                for _ in range(size):
                    batch.append(next(entries))
            except StopIteration:
                if batch:
                    yield batch
                return
            except Exception:
                if batch:
                    yield batch
                raise
            yield batch

    return itertools.chain.from_iterable(batches())


def _commands(text: str) -> list[str]:
    return [
        line for line in (command_of(raw.encode()) for raw in text.splitlines()) if line
    ]


def save_progress(stream: Stream, *, state: str | None = None) -> None:
    """Write how far the stream got (called at most about once a second)."""
    fields: dict[str, object] = {
        "lines_sent": stream.reached,
        "lines_acked": stream.done,
        "bytes_acked": stream.bytes_acked,
        "progress_at": shared_now(),
    }
    if state:
        fields["state"] = state
    Job.objects.filter(pk=stream.ref).update(**fields)
    broadcast.publisher().job(stream.ref, progress=None if state else fields)


def final_state(stream: Stream) -> Job.State:
    """The job state an ended stream's outcome gives."""
    return _OUTCOME_STATE.get(stream.outcome, Job.State.FAILED)


def reassert(stream: Stream, *, paused: bool) -> bool:
    """A run the control plane marked interrupted while this worker could not reach
    the database (`printers.reaper`) is running: say so again. True if it was."""
    back = Job.objects.filter(
        pk=stream.ref, state=Job.State.INTERRUPTED, message__contains=LAST_SAVED
    ).update(
        state=Job.State.PAUSED if paused else Job.State.PRINTING,
        message="",
        finished_at=None,
    )
    if back:
        history.forget_run(stream.ref)
        broadcast.publisher().job(stream.ref)
    return back == 1


def finish(stream: Stream) -> Job.State:
    """Record the stream's outcome on its job; returns the job's final state."""
    state = final_state(stream)
    Job.objects.filter(pk=stream.ref).update(
        state=state,
        message=stream.message,
        lines_sent=stream.reached,
        lines_acked=stream.done,
        bytes_acked=stream.bytes_acked,
        finished_at=shared_now(),
    )
    history.record_run(stream.ref)
    broadcast.publisher().job(stream.ref)
    return state


def fail_job(job: Job, message: str) -> None:
    """A claimed job that cannot even start (file gone): mark it failed."""
    Job.objects.filter(pk=job.pk).update(
        state=Job.State.FAILED, message=message, finished_at=shared_now()
    )
    history.record_run(job.pk)
    broadcast.publisher().job(job.pk)


def next_position(printer_id: int) -> int:
    """Queue position after every job of the printer."""
    last = (
        Job.objects.filter(printer_id=printer_id)
        .order_by(F("position").desc(nulls_last=True))
        .values_list("position", flat=True)
        .first()
    )
    return (last or 0) + 1
