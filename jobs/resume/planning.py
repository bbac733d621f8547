"""Resume plans, from the operator's choice to the queued run.

    plan = request_plan(job, line=..., layer=..., user=..., origin=...)  # the view
    make_plan(plan.pk)                        # the Celery task: read, rebuild, write
    resumed = start_plan(plan, ...)           # the view, once the operator agrees

`request_plan` checks everything it can without reading the file (the job's state,
its file, its analysis, the line or layer) and raises `ResumeRefused` with the
HTTP status and why; nothing is written then. `make_plan` reads the file up to
the line (or up to where the run stopped, if that is further) to rebuild the
machine's state, and writes the preamble. `start_plan` queues a new run of the
same file ahead of the printer's queue, linked to the old one.
"""

from __future__ import annotations

import logging
import re
from collections import deque
from typing import TYPE_CHECKING, Any

from django.db import transaction
from django.db.models import Min

from jobs.analysing import analysis_of
from jobs.commands import request_action
from jobs.eta import IN_FLIGHT
from jobs.gcode import BadGcode, iter_commands
from jobs.hostcache import sha256_of
from jobs.models import ACTIVE_STATES, FileAnalysis, Job, ResumePlan
from jobs.paths import PathRefused
from jobs.resume.preamble import ResumePoint, build_preamble
from jobs.resume.state import MachineState, StateReader, offsets_lost
from printers import broadcast
from printers.models import QueuedCommand
from printers.reaper import LAST_SAVED
from printers.streaming.object_places import place_at
from printers.worker.spool import file_entries, next_position

if TYPE_CHECKING:
    from django.contrib.auth.models import AbstractBaseUser

    from jobs.analysis.result import Analysis

logger = logging.getLogger(__name__)

#: States of a run that stopped before its end and can be resumed.
RESUMABLE = frozenset({Job.State.INTERRUPTED, Job.State.FAILED, Job.State.ABORTED})


class ResumeRefused(ValueError):
    """The plan or its start is refused; `status` is the HTTP status to answer."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


def request_plan(
    job: Job,
    *,
    line: int | None = None,
    layer: int | None = None,
    user: AbstractBaseUser | None = None,
    origin: str = "",
) -> ResumePlan:
    """Check the choice and store a pending plan; the task is sent once committed.

    *line* is a command index (0-based: the first command not printed yet);
    *layer* a 0-based index in the analysis' layers; neither: the line after the
    last one the firmware acknowledged.
    """
    _check_resumable(job)
    analysed = _analysis(job)
    if line is not None and layer is not None:
        raise ResumeRefused(400, "give a line or a layer, not both")
    if layer is not None:
        layers = analysed.layers
        if not 0 <= layer < len(layers):
            raise ResumeRefused(
                400, f"layer {layer} is not in the file: it has {len(layers)} layers "
                f"(0 to {len(layers) - 1})",
            )  # fmt: skip
        line = layers[layer].line
    if line is None:
        line = job.lines_acked
    if line < 0:
        raise ResumeRefused(400, f"line {line} is not in the file")
    if line >= job.line_count:
        raise ResumeRefused(
            400, f"line {line} is beyond the file: it has {job.line_count} commands, "
            f"so a resume starts at 0 to {job.line_count - 1}",
        )  # fmt: skip
    with transaction.atomic():
        plan = ResumePlan.objects.create(
            job=job, line=line, layer=layer, created_by=user, origin=origin
        )
        pk = plan.pk
        transaction.on_commit(lambda: send(pk))
    return plan


def _check_resumable(job: Job) -> None:
    if job.kind != Job.Kind.PRINT:
        raise ResumeRefused(
            409, f"job {job.pk} printed from the SD card: printhost did not stream it"
        )
    if job.state in ACTIVE_STATES or job.state == Job.State.QUEUED:
        raise ResumeRefused(
            409, f"job {job.pk} is {job.state}: only a run that stopped can resume"
        )
    if job.state not in RESUMABLE:
        raise ResumeRefused(
            409, f"job {job.pk} is {job.state}: only an interrupted, failed or "
            "aborted run can resume",
        )  # fmt: skip
    if job.file_removed_at is not None:
        raise ResumeRefused(
            410, f"job {job.pk}: its file was removed on {job.file_removed_at:%Y-%m-%d} "
            "(the printer's job_file_days)",
        )  # fmt: skip
    try:
        present = job.path.is_file()
    except PathRefused:
        present = False
    if not present:
        raise ResumeRefused(409, f"job {job.pk}: the stored file is gone")
    if LAST_SAVED in job.message:
        # The control plane marked it interrupted when the host fell silent: the
        # host may only be cut off, still printing it (it says so when it is back),
        # and the line it reached is in its journal, not here.
        raise ResumeRefused(
            409, f"job {job.pk}: its worker host stopped answering, and may still be "
            "printing it; a resume waits until a worker of the printer has settled "
            "the run from the host's journal (the host is back, or the printer was "
            "moved to another host)",
        )  # fmt: skip
    if sha256_of(job.path) != job.sha256:
        raise ResumeRefused(
            409, f"job {job.pk}: the stored file changed since the run (its SHA-256 "
            "is not the run's): its lines are not the ones printed",
        )  # fmt: skip


def _analysis(job: Job) -> Analysis:
    analysis = job.analysis
    state = analysis.state if analysis is not None else None
    if state != FileAnalysis.State.DONE:
        why = {
            None: "has no analysis",
            FileAnalysis.State.PENDING: "is not analysed yet",
            FileAnalysis.State.RUNNING: "is still being analysed",
            FileAnalysis.State.FAILED: "could not be analysed",
        }[state]
        raise ResumeRefused(
            409, f"job {job.pk}: its file {why}; a resume needs the analysis (the "
            "machine's state at each line, the layers)",
        )  # fmt: skip
    analysed = analysis_of(job)
    if analysed is None:
        raise ResumeRefused(409, f"job {job.pk}: its analysis cannot be read")
    return analysed


def send(pk: int) -> bool:
    """Hand the plan to Celery; a broker that is away fails the plan, saying so."""
    from jobs.tasks import plan_resume

    try:
        plan_resume.delay(pk)
    except Exception as error:  # any broker failure: the operator asks again
        logger.warning("resume plan %s not sent: %s", pk, error)
        ResumePlan.objects.filter(pk=pk, state=ResumePlan.State.PENDING).update(
            state=ResumePlan.State.FAILED,
            reason=f"the task queue is not reachable ({error}); try again",
        )
        return False
    return True


def make_plan(pk: int) -> str:
    """Read the file, rebuild the state at the plan's line, write the preamble."""
    plan = ResumePlan.objects.select_related("job__printer").filter(pk=pk).first()
    if plan is None or plan.state != ResumePlan.State.PENDING:
        return "skipped"
    job = plan.job
    try:
        point, offset = read_point(job, plan.line)
        objects = objects_at(job, plan.line)
    except (BadGcode, OSError, PathRefused) as error:
        ResumePlan.objects.filter(pk=pk).update(
            state=ResumePlan.State.FAILED, reason=f"the file cannot be read: {error}"
        )
        return "failed"
    lost = offsets_lost(point.state)
    if lost:
        ResumePlan.objects.filter(pk=pk).update(
            state=ResumePlan.State.FAILED,
            reason=(
                f"the file's G92 offset on {', '.join(lost)} cannot be put back at "
                "this line (the file set it, or the axis moved, where printhost "
                "cannot follow: a G53, G28, G30 or probing move): the resume would "
                "cut in the wrong place; pick another line, or run the file again"
            ),
        )
        return "failed"
    machine = point.state.as_dict()
    machine.update(start_offset=offset, stop_z=point.stop_z, warnings=point.warnings)
    if objects is not None:
        machine["objects"] = objects
    ResumePlan.objects.filter(pk=pk, state=ResumePlan.State.PENDING).update(
        state=ResumePlan.State.READY,
        preamble="\n".join(build_preamble(point)),
        machine=machine,
    )
    broadcast.publisher().job(job.pk)
    return "ready"


def read_point(job: Job, line: int) -> tuple[ResumePoint, int]:
    """The state at *line* and where its text begins (0 for a binary file)."""
    printer = job.printer
    stop = max(job.lines_acked, 0)
    reader = StateReader(printer.firmware)
    # Where the nozzle may be: the Z after each of the last IN_FLIGHT moves the
    # firmware acknowledged (its planner holds moves, not other commands), and the
    # Z before the oldest of them, which may not have run yet either.
    recent: deque[float] = deque([reader.state.position[2]], maxlen=IN_FLIGHT + 1)
    at_line = None
    offset = start = 0
    for command in iter_commands(job.path):
        if command.index == line:
            at_line = reader.state.as_dict()
        if command.index >= max(line, stop):
            break
        reader.feed(command.text)
        if command.index < stop and _MOVE.match(command.text):
            recent.append(reader.state.position[2])
        offset = command.end_offset
        if command.index + 1 == line:
            start = offset
    if at_line is None:
        raise BadGcode(f"line {line} is beyond the file's {reader.commands} commands")
    state = MachineState.from_dict(at_line)
    stop_z = min(recent) if recent else state.position[2]
    warnings = []
    warnings += _unknown_axes(state)
    if state.known[2] and state.position[2] < stop_z - 1e-6:
        warnings.append(
            f"the resume height ({state.position[2]:g} mm) is below where the print "
            f"stopped ({stop_z:g} mm): the nozzle goes down into what was printed"
        )
    if state.firmware != "grbl" and not state.heaters:
        warnings.append("the file set no temperatures before this line")
    point = ResumePoint(
        line=line,
        state=state,
        stop_z=stop_z,
        home_z=printer.resume_home_z,
        lift=printer.resume_lift_mm,
        warnings=warnings,
    )
    return point, start


def _unknown_axes(state: MachineState) -> list[str]:
    """CNC: what the preamble leaves to the file, for axes a move before the line
    took where the file's coordinates cannot follow (`StateReader._lose`)."""
    if state.firmware != "grbl":
        return []
    warnings = []
    if not state.known[2]:
        warnings.append(
            "Z at this line is where a G53, G28, G30 or probing move left it, which "
            "printhost cannot place: the tool stays at the safe height until the "
            "file's next Z move"
        )
    flat = [
        letter for letter, known in zip("XY", state.known, strict=False) if not known
    ]
    if flat:
        warnings.append(
            f"{' and '.join(flat)} at this line cannot be placed either: the tool "
            "goes there with the file's next move, at the safe height"
        )
    return warnings


def objects_at(job: Job, line: int) -> dict[str, Any] | None:
    """Which object streams at *line* and the `M486 S` numbers named before it,
    for the resumed run's object filter (rule O10 in printers/streaming/objects.py);
    None for a file without objects."""
    if not job.objects_list():
        return None
    return place_at(file_entries(job.path, start_index=0, start_offset=0), line)


#: A command the firmware's planner holds (G0 to G3).
_MOVE = re.compile(r"\s*[Gg]0*[0-3](?![\d.])")


def start_plan(
    plan: ResumePlan, *, user: AbstractBaseUser | None = None, origin: str = ""
) -> Job:
    """Queue the resumed run ahead of the printer's queue; the plan is used up."""
    with transaction.atomic():
        locked = ResumePlan.objects.select_for_update().get(pk=plan.pk)
        if locked.state != ResumePlan.State.READY:
            raise ResumeRefused(
                409, f"resume plan {plan.pk} is {locked.state}, not ready to start"
            )
        job = Job.objects.select_related("printer").get(pk=locked.job_id)
        _check_resumable(job)
        printer = job.printer
        busy = Job.objects.filter(printer=printer, state__in=ACTIVE_STATES).first()
        if busy is not None:
            raise ResumeRefused(
                409, f"{printer.slug} is printing job {busy.pk}: a resume waits for an "
                "idle printer with the part on its bed",
            )  # fmt: skip
        first = Job.objects.filter(printer=printer, state=Job.State.QUEUED).aggregate(
            first=Min("position")
        )["first"]
        resumed = Job.objects.create(
            printer=printer,
            name=job.name,
            kind=job.kind,
            file=job.file,
            size_bytes=job.size_bytes,
            line_count=job.line_count,
            sha256=job.sha256,
            analysis=job.analysis,
            position=(first - 1) if first is not None else next_position(printer.pk),
            origin=origin,
            uploaded_by=user,
            resume_of=job,
            start_line=locked.line,
            start_offset=int(locked.machine.get("start_offset", 0)),
            preamble=locked.preamble,
            cancelled_objects=job.cancelled_objects,
            start_objects=locked.machine.get("objects") or {},
            lines_acked=locked.line,
            lines_sent=locked.line,
            bytes_acked=int(locked.machine.get("start_offset", 0)),
        )
        locked.state = ResumePlan.State.STARTED
        locked.resumed = resumed
        locked.save(update_fields=["state", "resumed"])
        # Starting a resume is the operator saying what is on the bed: the part
        # this run continues. The worker's waitstart (kept since the stop) ends.
        request_action(printer, QueuedCommand.Action.BED_CLEAR, origin=origin)
    broadcast.publisher().job(resumed.pk)
    return resumed
