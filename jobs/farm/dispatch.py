"""The dispatcher: gives waiting farm jobs to free matching printers, atomically.

One pass (`Dispatcher.run_pass`) reads the farm's printers once, walks the waiting
jobs in queue order, and claims each job a free printer can take. A claim
(`claim`) is one transaction:

1. Take the farm job: on PostgreSQL `SELECT … FOR UPDATE SKIP LOCKED` of the row,
   still waiting (another dispatcher's claim in flight is skipped, not waited
   for); elsewhere (SQLite, whose transactions here begin IMMEDIATE and so hold
   the one write lock) a conditional UPDATE from waiting.
2. Take the printer: its row locked the same way (PostgreSQL), then read again
   and checked again: enabled, farm, idle, its worker's lease alive, no job of its
   own queued or running, the requirements met.
3. Queue the printer's `Job` through `jobs.services` (the file hard-linked into
   its storage, the job's analysis asked for), and mark the farm job assigned
   with that job and printer.

Two dispatchers therefore never give one job twice (the farm job's row is
locked, or updated only from waiting) and never give one printer two jobs (the
printer's row is locked and its queue read again under that lock). A dispatcher
killed inside the transaction gives nothing: the database rolls it back, and
the link it may have made is replaced by the next attempt, which uses the same
name. The farm's copy of the file goes once the printer's job holds it.
"""

from __future__ import annotations

import logging
from collections import defaultdict
from dataclasses import dataclass
from typing import TYPE_CHECKING

from django.db import connection, transaction
from django.db.models.functions import Now
from django.utils import timezone

from jobs import services
from jobs.farm.matching import (
    OWN_WORK,
    busy_reason,
    decide,
    every_waiting_job,
    facts_of,
    farm_printers,
    part_of,
)
from jobs.farm.models import FarmJob
from jobs.farm.requirements import unmet
from jobs.farm.storing import remove_file, request_farm_analysis
from jobs.gcode import BadGcode, FileFacts
from jobs.models import Job
from jobs.paths import PathRefused
from printers.models import Printer

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

logger = logging.getLogger("printhost.farm")

#: Attempts per job and pass when a claim loses its printer to another claimant.
CLAIM_ATTEMPTS = 3


class _Refused(Exception):
    """The claim cannot go on: roll the transaction back."""

    def __init__(self, lost: str, why: str) -> None:
        super().__init__(why)
        self.lost = lost


def _locks_rows() -> bool:
    return bool(connection.features.has_select_for_update_skip_locked)


#: Why a claim gave nothing: the job is gone or held by another claim (try the
#: next job), or the printer is (try another printer for this job).
JOB_TAKEN, PRINTER_TAKEN = "job", "printer"


@dataclass(frozen=True)
class Claim:
    """What a claim did: the printer's new job, or which row it lost."""

    job: Job | None = None
    lost: str = ""


def _take_rows(farm_job_id: int, printer_id: int) -> tuple[FarmJob, Printer]:
    """Step 1 and 2's taking: the farm job (still waiting) and the printer rows."""
    waiting = FarmJob.objects.filter(pk=farm_job_id, state=FarmJob.State.WAITING)
    if _locks_rows():
        farm_job = waiting.select_for_update(skip_locked=True).first()
        if farm_job is None:
            raise _Refused(JOB_TAKEN, "gone, or held by another claim")
        printer = (
            Printer.objects.select_for_update(skip_locked=True)
            .annotate(db_now=Now())  # its lease is judged by the database's clock
            .filter(pk=printer_id)
            .first()
        )
    else:
        if not waiting.update(state=FarmJob.State.ASSIGNED):
            raise _Refused(JOB_TAKEN, "no longer waiting")
        farm_job = FarmJob.objects.get(pk=farm_job_id)
        printer = Printer.objects.annotate(db_now=Now()).filter(pk=printer_id).first()
    if printer is None:
        raise _Refused(PRINTER_TAKEN, "held by another claim, or gone")
    return farm_job, printer


def recheck(farm_job: FarmJob, printer: Printer) -> str:
    """Why *printer* (its row just read under the claim) cannot take *farm_job*
    ("" when it can)."""
    has_work = Job.objects.filter(printer=printer, state__in=OWN_WORK).exists()
    if printer.firmware == Printer.Firmware.GRBL:
        return "a GRBL machine takes no farm jobs"
    busy = busy_reason(printer, has_work=has_work)
    if busy:
        return busy
    part = part_of(farm_job)
    if isinstance(part, str):
        return part
    missing = unmet(farm_job.requirements, part, facts_of(printer, has_work=has_work))
    return f"does not meet the job's {missing} requirement" if missing else ""


def link_name(farm_job: FarmJob) -> str:
    """The file's name in the printer's storage: the same for every attempt."""
    return f"farm{farm_job.pk}-{farm_job.name}"


def claim(
    farm_job_id: int,
    printer_id: int,
    *,
    hook: Callable[[FarmJob, Printer], None] | None = None,
) -> Claim:
    """Give the farm job to the printer (the module's steps 1-3): the printer's new
    job, or which row was lost (taken by another claim, or the re-check failed)."""
    target: Path | None = None
    try:
        with transaction.atomic():
            farm_job, printer = _take_rows(farm_job_id, printer_id)
            problem = recheck(farm_job, printer)
            if problem:
                raise _Refused(PRINTER_TAKEN, problem)
            if hook is not None:
                hook(farm_job, printer)
            target = services.stored_file(
                printer, services.safe_name(link_name(farm_job))
            )
            job = services.enqueue_checked_file(
                printer,
                farm_job.path,
                name=farm_job.name,
                facts=FileFacts(
                    farm_job.size_bytes,
                    farm_job.line_count,
                    farm_job.sha256,
                    farm_job.longest_command,
                ),
                stored_as=link_name(farm_job),
                origin=f"farm job {farm_job.pk}: {farm_job.origin}"[:100],
                user=farm_job.uploaded_by,
            )
            FarmJob.objects.filter(pk=farm_job.pk).update(
                state=FarmJob.State.ASSIGNED,
                job=job,
                printer=printer,
                assigned_at=timezone.now(),
                reason="",
            )
    except _Refused as refusal:
        logger.info(
            "farm job %s not given to printer %s: the %s is %s",
            farm_job_id,
            printer_id,
            refusal.lost,
            refusal,
        )
        return Claim(lost=refusal.lost)
    except BaseException:
        if (
            target is not None
            and not Job.objects.filter(file__endswith=target.name).exists()
        ):
            target.unlink(missing_ok=True)
        raise
    logger.info(
        "farm job %s (%s) given to %s as job %s",
        farm_job.pk,
        farm_job.name,
        printer.slug,
        job.pk,
    )
    farm_job.refresh_from_db()
    remove_file(farm_job)
    return Claim(job=job)


class Dispatcher:
    """Passes over the farm queue (`run_pass`); the command loops over them."""

    def __init__(
        self, *, hook: Callable[[FarmJob, Printer], None] | None = None
    ) -> None:
        self.hook = hook
        #: Claims lost to another claimant or to a failed re-check, since start.
        self.lost = 0

    def run_pass(self) -> int:
        """Give every waiting job a free printer can take; write why the others
        wait. Returns how many jobs were given.

        1. Read the farm's printers once; walk every waiting job in queue order
           (`every_waiting_job`, read in batches).
        2. For each, decide (`matching.decide`) with the printers given a job in
           this pass left out; claim. When the claim loses the printer, leave it
           out too and decide again (at most `CLAIM_ATTEMPTS` times); when it loses
           the job (another claim holds it), go on to the next job.

        One dispatcher gives jobs in queue order. Several at once keep it only
        roughly: a job whose claim fails late may see a later one take the last
        free printer; it goes at the next pass.
        3. Write the reason of every job still waiting whose reason changed.
        4. Remove farm copies an earlier pass left behind (killed after a claim).
        """
        printers = farm_printers()
        taken: set[str] = set()
        given = 0
        changed: dict[str, list[int]] = defaultdict(list)
        for farm_job in every_waiting_job():
            if farm_job.analysis_id is None:  # its row was removed: ask again
                request_farm_analysis(farm_job)
            reason = ""
            for _attempt in range(CLAIM_ATTEMPTS):
                decision = decide(farm_job, printers, taken)
                reason = decision.reason
                if decision.printer is None:
                    break
                taken.add(decision.printer.slug)
                try:
                    outcome = claim(
                        farm_job.pk, decision.printer.extra["pk"], hook=self.hook
                    )
                except (OSError, BadGcode, PathRefused) as error:
                    # This job's file, not the farm: the jobs behind it go on.
                    reason = f"could not be given to {decision.printer.slug}: {error}"
                    logger.warning("farm job %s %s", farm_job.pk, reason)
                    break
                if outcome.job is not None:
                    given += 1
                    reason = ""
                    break
                self.lost += 1
                if outcome.lost == JOB_TAKEN:
                    # Another claim holds the job: its printer stays left out, as
                    # that claim will most likely take it.
                    reason = ""
                    break
            if reason and reason != farm_job.reason:
                changed[reason].append(farm_job.pk)
        # One UPDATE per distinct reason: a busy farm's jobs mostly share one.
        for reason, ids in changed.items():
            FarmJob.objects.filter(pk__in=ids, state=FarmJob.State.WAITING).update(
                reason=reason
            )
        self.tidy()
        return given

    @staticmethod
    def tidy() -> None:
        """Remove the farm copy of assigned jobs that still have one."""
        left = FarmJob.objects.filter(state=FarmJob.State.ASSIGNED).exclude(file="")
        for farm_job in left[:100]:
            remove_file(farm_job)
