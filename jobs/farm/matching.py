"""Which printer a waiting farm job goes to, and why it waits when none.

A printer can take a farm job when it is enabled, takes farm jobs (`farm`), is a
3D printer (the farm analyses files as prints; GRBL machines take none), is
`idle` (connected, bed confirmed clear: `waitstart` is not), its worker holds its
lease (a dead worker's row may still say idle), no job of its own is queued or
running, and it meets the job's requirements (`jobs.farm.requirements`).

Among the printers that can take a job, the dispatcher prefers the one with the
smallest build volume that fits, so the large machines stay free for the parts
only they can print; then the one idle longest (its last job ended first: the
work and the wear spread evenly); then by slug, so the choice is repeatable.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from django.db.models import Exists, OuterRef, Subquery
from django.db.models.functions import Now

from jobs.farm.models import FarmJob
from jobs.farm.requirements import (
    Part,
    PrinterFacts,
    box_of,
    matching,
    volume_size,
    why_none_match,
)
from jobs.farm.storing import WAITING_FOR_ANALYSIS
from jobs.models import FileAnalysis, Job
from printers.dbclock import database_now
from printers.driver import LinkConfig
from printers.models import Printer

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator, Sequence

    from django.db.models import QuerySet


#: Job states that keep a printer from taking a farm job.
OWN_WORK = (Job.State.QUEUED, Job.State.PRINTING, Job.State.PAUSED)
#: Printers named in a "busy" reason before "and n more".
NAMED = 4
_NEVER = datetime.min.replace(tzinfo=UTC)


def printer_rows() -> QuerySet[Printer]:
    """Printers by slug with their host and what the farm reads of their jobs:
    `has_work` (one of their own queued or running) and `last_end` (when their last
    job finished)."""
    own_work = Job.objects.filter(printer=OuterRef("pk"), state__in=OWN_WORK)
    # The newest end by the (printer, finished_at) index: one row a printer, where
    # a Max over the join read every job the printer ever ran on each poll.
    ends = Job.objects.filter(printer=OuterRef("pk"), finished_at__isnull=False)
    newest_end = ends.order_by("-finished_at").values("finished_at")[:1]
    return (
        Printer.objects.select_related("worker_host")
        .annotate(
            has_work=Exists(own_work),
            last_end=Subquery(newest_end),
            db_now=Now(),  # leases are judged by the database's clock
        )
        .order_by("slug")
    )


def takes_farm_jobs(printer: Printer) -> bool:
    """The printer is one the farm may use (enabled, `farm`, not GRBL)."""
    return printer.enabled and printer.farm and not printer.is_grbl


def farm_printers(rows: Iterable[Printer] | None = None) -> list[PrinterFacts]:
    """Every printer the farm may use, with what keeps it from a job now (if any):
    read, or picked from *rows* (`printer_rows()` read once for a whole view)."""
    if rows is None:
        rows = printer_rows().filter(enabled=True, farm=True)
        rows = rows.exclude(firmware=Printer.Firmware.GRBL)
    return [
        facts_of(p, has_work=p.has_work, last_end=p.last_end)
        for p in rows
        if takes_farm_jobs(p)
    ]


def facts_of(
    printer: Printer, *, has_work: bool, last_end: datetime | None = None
) -> PrinterFacts:
    """What the matcher knows of *printer*; `extra["busy"]` says why it cannot take a
    job now ("" when it can)."""
    return PrinterFacts(
        slug=printer.slug,
        material=printer.material,
        colour=printer.colour,
        nozzle=printer.nozzle_diameter,
        profile=printer.profile,
        tags=tuple(printer.tags or ()),
        volume=box_of(printer.build_volume),
        command_limit=LinkConfig.from_printer(printer).command_limit,
        extra={
            "pk": printer.pk,
            "name": printer.name,
            "host": printer.worker_host.name if printer.worker_host_id else "",
            "busy": busy_reason(printer, has_work=has_work),
            "last_end": last_end,
        },
    )


def busy_reason(printer: Printer, *, has_work: bool) -> str:
    """Why *printer* cannot take a farm job now, in a few words ("" if it can).

    Its lease is judged by the database's clock, as its worker wrote it
    (`printers/dbclock.py`): the row's `db_now` when it was read with it (as
    `printer_rows()` and the claim read it), else asked for."""
    if not printer.enabled or not printer.farm:
        return "takes no farm jobs"
    expires = printer.lease_expires_at
    if printer.state == Printer.State.OFFLINE:
        return "offline"
    if expires is None or expires <= _database_now_of(printer):
        return "offline (no worker holds it)"
    if printer.state == Printer.State.WAITSTART:
        return "waiting for its bed to be cleared"
    if printer.state != Printer.State.IDLE:
        return Printer.State(printer.state).label
    if has_work:
        return "has a job queued"
    return ""


def _database_now_of(printer: Printer) -> datetime:
    now = getattr(printer, "db_now", None)
    return database_now() if now is None else now


def preference(printer: PrinterFacts) -> tuple[float, datetime, str]:
    """Smallest build volume first, then idle longest, then slug (module docstring)."""
    return (
        volume_size(printer.volume),
        printer.extra.get("last_end") or _NEVER,
        printer.slug,
    )


@dataclass(frozen=True)
class Decision:
    """Where a farm job goes now (`printer`), or why it waits (`reason`)."""

    printer: PrinterFacts | None = None
    reason: str = ""
    #: The printers that meet its requirements, free or not.
    matching: list[PrinterFacts] = field(default_factory=list)


def part_of(farm_job: FarmJob) -> Part | str:
    """The file's box and longest command, or why they are not known yet."""
    analysis = farm_job.analysis
    if analysis is None:
        return WAITING_FOR_ANALYSIS
    if analysis.state == FileAnalysis.State.FAILED:
        return (
            f"the file's analysis failed ({analysis.reason or 'no reason given'}): "
            "without its size no printer can be chosen; analyse it again or cancel"
        )
    if analysis.state != FileAnalysis.State.DONE:
        progress = analysis.as_dict(size=farm_job.size_bytes).get("progress")
        return WAITING_FOR_ANALYSIS + (
            f" ({progress:g} % read)" if progress is not None else ""
        )
    return Part(
        box=box_of(analysis.summary.get("bbox")), longest=farm_job.longest_command
    )


def decide(
    farm_job: FarmJob, printers: Sequence[PrinterFacts], taken: Iterable[str] = ()
) -> Decision:
    """Where *farm_job* goes among *printers* (*taken*: slugs given a job already in
    this pass), or why it waits."""
    part = part_of(farm_job)
    if isinstance(part, str):
        return Decision(reason=part)
    req = farm_job.requirements
    fitting = matching(req, part, printers)
    if not fitting:
        return Decision(reason=why_none_match(req, part, printers))
    gone = set(taken)
    free = [p for p in fitting if not p.extra["busy"] and p.slug not in gone]
    if not free:
        return Decision(reason=waiting_reason(fitting, gone), matching=fitting)
    return Decision(printer=min(free, key=preference), matching=fitting)


def waiting_reason(fitting: Sequence[PrinterFacts], taken: set[str]) -> str:
    """`every matching printer is busy: mk3-a printing, mk3-b waiting for its bed to
    be cleared`."""
    states = [
        f"{p.slug} {'was just given a job' if p.slug in taken else p.extra['busy']}"
        for p in fitting
    ]
    more = len(states) - NAMED
    listed = ", ".join(states[:NAMED]) + (f" and {more} more" if more > 0 else "")
    one = len(fitting) == 1
    return (
        f"the one matching printer is busy: {listed}"
        if one
        else f"every matching printer is busy: {listed}"
    )


def waiting_jobs(limit: int = 500) -> list[FarmJob]:
    """The first *limit* waiting farm jobs in queue order (priority, deadline, age)."""
    return list(_waiting().order_by(*FarmJob._meta.ordering)[:limit])


def every_waiting_job(batch: int = 500) -> Iterator[FarmJob]:
    """Every waiting farm job in queue order, read *batch* at a time: a dispatcher's
    pass sees the whole queue, so jobs that must wait at its head (for their
    analysis, or a printer no one has) never keep the ones behind from a free
    printer. The order is read first, as ids: jobs given meanwhile shift nothing."""
    order = _waiting().order_by(*FarmJob._meta.ordering).values_list("pk", flat=True)
    ids = list(order)
    for start in range(0, len(ids), batch):
        chunk = ids[start : start + batch]
        rows = _waiting().in_bulk(chunk)
        yield from (rows[pk] for pk in chunk if pk in rows)


def _waiting() -> QuerySet[FarmJob]:
    return (
        FarmJob.objects.filter(state=FarmJob.State.WAITING)
        .select_related("analysis")
        .defer("analysis__result")
    )


def plan(
    farm_jobs: Sequence[FarmJob], printers: Sequence[PrinterFacts]
) -> list[tuple[FarmJob, Decision]]:
    """What a dispatcher's pass would do now: each job in queue order takes the best
    free printer left (the farm view's "would go to")."""
    taken: set[str] = set()
    out = []
    for farm_job in farm_jobs:
        decision = decide(farm_job, printers, taken)
        if decision.printer is not None:
            taken.add(decision.printer.slug)
        out.append((farm_job, decision))
    return out


def printer_summary(printer: PrinterFacts) -> dict[str, Any]:
    """A farm printer as the farm API lists it."""
    return {
        "slug": printer.slug,
        "name": printer.extra.get("name", ""),
        "host": printer.extra.get("host", ""),
        "material": printer.material,
        "colour": printer.colour,
        "nozzle_diameter": printer.nozzle,
        "profile": printer.profile,
        "tags": list(printer.tags),
        "build_volume": None
        if printer.volume is None
        else {"min": list(printer.volume[0]), "max": list(printer.volume[1])},
        "free": not printer.extra.get("busy"),
        "busy": printer.extra.get("busy", ""),
    }
