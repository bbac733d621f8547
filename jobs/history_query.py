"""Reading the print history: filtered lists of runs and totals over a period.

A list holds the ended runs (`HistoryEntry` rows) and the running ones (Job rows
printing or paused, `history.running_dict`), in one order: by start time, newest
first unless asked otherwise; an ended run comes before a running one that started
at the same instant. The period filters the start time: `since` included, `before`
excluded. Totals count ended runs only (a running run has no outcome yet).

Who may read what is the caller's business (`printhost.api.print_history`): a query
names the printers it may read.
"""

from __future__ import annotations

import heapq
import itertools
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypedDict

from django.db.models import Count, Max, Q, QuerySet, Sum

from jobs.history import HistoryEntry, Outcome, running_dict
from jobs.models import ACTIVE_STATES, Job

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator
    from datetime import datetime

    from jobs.history import RunDict, RunLink

#: What `outcome` may filter on: an outcome, or "resumed" (runs that resume another).
OUTCOME_FILTERS = (*Outcome.values, "resumed")
#: What totals may be grouped by, and the entry field each group is keyed on.
GROUPS = {"printer": "printer_slug", "user": "user_name", "file": "sha256"}


@dataclass(frozen=True, slots=True)
class HistoryQuery:
    """Which runs: the printers readable, then the caller's filters."""

    #: Printers whose runs may be read (None: every printer).
    printer_ids: frozenset[int] | None = None
    #: Entries whose printer was deleted may be read too.
    orphans: bool = False
    printer_id: int | None = None
    user: str | None = None
    outcome: str | None = None
    since: datetime | None = None
    before: datetime | None = None
    ascending: bool = False


@dataclass(frozen=True, slots=True)
class Page:
    """One page of a list: *count* runs match in all."""

    count: int
    runs: list[RunDict]


class TotalsRow(TypedDict):
    key: str
    label: str
    jobs: int
    completed: int
    success_rate: float | None
    print_seconds: float
    print_hours: float
    filament_used: float
    longest_seconds: float


def ended(query: HistoryQuery) -> QuerySet[HistoryEntry]:
    """The ended runs the query names (not ordered)."""
    found = HistoryEntry.objects.all()
    if query.printer_ids is not None:
        scope = Q(printer_id__in=query.printer_ids)
        if query.orphans:
            scope |= Q(printer__isnull=True)
        found = found.filter(scope)
    if query.printer_id is not None:
        found = found.filter(printer_id=query.printer_id)
    if query.user is not None:
        found = found.filter(user_name=query.user)
    if query.outcome == Outcome.IN_PROGRESS:
        return found.none()
    if query.outcome == "resumed":
        found = found.filter(resumed_from__isnull=False)
    elif query.outcome is not None:
        found = found.filter(outcome=query.outcome)
    if query.since is not None:
        found = found.filter(started_at__gte=query.since)
    if query.before is not None:
        found = found.filter(started_at__lt=query.before)
    return found


def running(query: HistoryQuery) -> list[Job]:
    """The running runs the query names, in the query's order."""
    if query.outcome not in (None, Outcome.IN_PROGRESS, "resumed"):
        return []
    found = Job.objects.filter(
        state__in=ACTIVE_STATES, started_at__isnull=False
    ).exclude(kind=Job.Kind.SD_UPLOAD)
    if query.printer_ids is not None:
        found = found.filter(printer_id__in=query.printer_ids)
    if query.printer_id is not None:
        found = found.filter(printer_id=query.printer_id)
    if query.user is not None:
        found = found.filter(uploaded_by__username=query.user)
    if query.outcome == "resumed":
        found = found.filter(resume_of__isnull=False)
    if query.since is not None:
        found = found.filter(started_at__gte=query.since)
    if query.before is not None:
        found = found.filter(started_at__lt=query.before)
    jobs = list(
        found.select_related("printer", "uploaded_by", "analysis").defer(
            "analysis__result"
        )
    )
    jobs.sort(key=lambda job: (job.started_at, job.pk), reverse=not query.ascending)
    return jobs


def _order(query: HistoryQuery) -> tuple[str, str]:
    return ("started_at", "id") if query.ascending else ("-started_at", "-id")


def page(query: HistoryQuery, *, limit: int, offset: int = 0) -> Page:
    """Runs *offset* to *offset* + *limit* of the list, and how many match.

    1. Find where each running run stands in the list: the ended runs that come
       before it, plus the running runs before it (a few: one per printer).
    2. Take the page's running runs by those places, and fill the other places
       with ended runs read by offset from the database.
    """
    entries = ended(query)
    live = running(query)
    places = []
    for index, job in enumerate(live):
        if query.ascending:
            ahead = entries.filter(started_at__lte=job.started_at)
        else:
            ahead = entries.filter(started_at__gte=job.started_at)
        places.append(ahead.count() + index)
    count = entries.count() + len(live)
    end = offset + limit
    slots: dict[int, Job] = {
        place - offset: job
        for job, place in zip(live, places, strict=True)
        if offset <= place < end
    }
    size = max(0, min(limit, count - offset))
    first = offset - sum(1 for place in places if place < offset)
    wanted = size - len(slots)
    rows = iter(entries.order_by(*_order(query))[first : first + max(0, wanted)])
    items: list[HistoryEntry | Job] = []
    for index in range(size):
        item = slots.get(index) or next(rows, None)
        if item is not None:  # an entry written since the count: the page is short
            items.append(item)
    return Page(count=count, runs=as_dicts(items))


def iter_runs(query: HistoryQuery, *, chunk: int = 500) -> Iterator[RunDict]:
    """Every run the query names, in order, read *chunk* entries at a time (CSV)."""
    live = running(query)
    entries = ended(query).order_by(*_order(query)).iterator(chunk_size=chunk)

    def when(item: HistoryEntry | Job) -> tuple[Any, int]:
        # Ended runs before running ones on the same instant, as `page` places them.
        started = item.started_at
        if query.ascending:
            return (started, 0 if isinstance(item, HistoryEntry) else 1)
        return (started, 1 if isinstance(item, HistoryEntry) else 0)

    merged = heapq.merge(entries, live, key=when, reverse=not query.ascending)
    while batch := list(itertools.islice(merged, chunk)):
        yield from as_dicts(batch)


def as_dicts(items: Iterable[HistoryEntry | Job]) -> list[RunDict]:
    """The runs' dictionaries, with which jobs still exist and which resumed them."""
    items = list(items)
    numbers = {_number(item) for item in items}
    origins = {origin for item in items if (origin := _resumed_from(item)) is not None}
    later: dict[int, set[int]] = {}
    resumes = itertools.chain(
        HistoryEntry.objects.filter(resumed_from__in=numbers).values_list(
            "resumed_from", "job_number"
        ),
        Job.objects.filter(resume_of__in=numbers, started_at__isnull=False).values_list(
            "resume_of_id", "pk"
        ),
    )
    for origin, number in resumes:
        later.setdefault(origin, set()).add(number)
    linked = numbers | origins | {n for runs in later.values() for n in runs}
    existing = set(Job.objects.filter(pk__in=linked).values_list("pk", flat=True))

    def links(number: int) -> list[RunLink]:
        return [
            {"job": n, "exists": n in existing} for n in sorted(later.get(number, ()))
        ]

    out: list[RunDict] = []
    for item in items:
        if isinstance(item, HistoryEntry):
            resumed_by = links(item.job_number)
            out.append(item.as_dict(existing=existing, resumed_by=resumed_by))
        else:
            run = running_dict(item, existing=existing)
            run["resumed_by"] = links(item.pk)
            out.append(run)
    return out


def _number(item: HistoryEntry | Job) -> int:
    return item.job_number if isinstance(item, HistoryEntry) else item.pk


def _resumed_from(item: HistoryEntry | Job) -> int | None:
    return item.resumed_from if isinstance(item, HistoryEntry) else item.resume_of_id


def totals(query: HistoryQuery, group: str | None = None) -> dict[str, Any]:
    """Ended runs counted over the query: overall, and by *group* if named.

    `jobs` counts ended runs, `completed` those that completed; `success_rate` is
    completed over ended (None without runs); `print_seconds` and `filament_used`
    (mm; runs of unanalysed files count 0) add up over the groups to the overall
    figures.
    """
    entries = ended(query)
    overall = _row("", "all", entries.aggregate(**_FIGURES))
    groups: list[TotalsRow] = []
    if group is not None:
        field = GROUPS[group]
        rows = (
            entries.order_by()
            .values(field)
            .annotate(label=Max(_LABELS[group]), **_FIGURES)
            .order_by(field)
        )
        for row in rows:
            key = row[field] or ""
            groups.append(_row(key, _label(group, key, row["label"]), row))
        groups.sort(key=lambda row: (-row["print_seconds"], row["label"]))
    return {"group": group, "overall": overall, "groups": groups}


#: What names a group to people: the printer's name, the user, the file's name.
_LABELS = {"printer": "printer_name", "user": "user_name", "file": "name"}
_FIGURES = {
    "jobs": Count("id"),
    "completed": Count("id", filter=Q(outcome=Outcome.COMPLETED)),
    "seconds": Sum("print_seconds"),
    "filament": Sum("filament_used"),
    "longest": Max("print_seconds"),
}


def _label(group: str, key: str, label: str | None) -> str:
    if group == "file" and not key:
        return "files without a SHA-256 (printed from the SD card)"
    if group == "user" and not key:
        return "nobody known"
    return label or key


def _row(key: str, label: str, figures: dict[str, Any]) -> TotalsRow:
    jobs = figures["jobs"] or 0
    completed = figures["completed"] or 0
    seconds = float(figures["seconds"] or 0.0)
    return {
        "key": key,
        "label": label,
        "jobs": jobs,
        "completed": completed,
        "success_rate": round(completed / jobs, 4) if jobs else None,
        "print_seconds": round(seconds, 1),
        "print_hours": round(seconds / 3600, 2),
        "filament_used": round(float(figures["filament"] or 0.0), 1),
        "longest_seconds": round(float(figures["longest"] or 0.0), 1),
    }
