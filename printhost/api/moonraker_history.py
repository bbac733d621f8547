"""Moonraker's job history calls, for the apps that speak Moonraker (Mainsail,
Fluidd, mobile apps): the history of one printer, in Moonraker's shapes.

    GET /server/history/list     limit (50), start (0), since, before (Unix
                                 seconds, on the start time), order (desc, asc)
    GET /server/history/job      uid: one run
    GET /server/history/totals   the printer's totals

Like every Moonraker path here, each is also served under `/p/<slug>/`, and the
printer is chosen as for any Moonraker call (`dialects.choose_printer`). A run's
`job_id` is its history entry's id as six hex digits; a run still printing has no
entry yet and is `job-<job id>` until it ends. Statuses: completed, cancelled
(aborted), error (failed), interrupted, in_progress. Moonraker's reset of the
totals and deletion of entries are not offered: the history is the record of what
the printers did.
"""

from __future__ import annotations

import re
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from django.http import HttpRequest, HttpResponse, JsonResponse
from ninja import Router
from ninja.errors import HttpError

from jobs.history import HistoryEntry, Outcome
from jobs.history_query import HistoryQuery, as_dicts, page, totals
from jobs.models import ACTIVE_STATES, Job
from printhost.api.common import parse_int
from printhost.api.dialects import choose_printer, dialect_route
from printhost.api.moonraker import moonraker_errors
from printhost.models import Role

if TYPE_CHECKING:
    from jobs.history import RunDict
    from printers.models import Printer

router = Router(tags=["Moonraker dialect"])

#: printhost's outcome -> Moonraker's job status.
STATUS = {
    Outcome.COMPLETED: "completed",
    Outcome.ABORTED: "cancelled",
    Outcome.FAILED: "error",
    Outcome.INTERRUPTED: "interrupted",
    Outcome.IN_PROGRESS: "in_progress",
}
#: The analysis' figures under Moonraker's metadata names.
METADATA = {
    "estimated_seconds": "estimated_time",
    "filament_total": "filament_total",
    "filament_weight_g": "filament_weight_total",
    "layers": "layer_count",
    "layer_height": "layer_height",
    "first_layer_height": "first_layer_height",
    "object_height": "object_height",
    "slicer": "slicer",
    "slicer_version": "slicer_version",
    "material": "filament_type",
}
#: The most runs one list call returns.
MAX_LIMIT = 1000
_ENTRY_UID = re.compile(r"^[0-9A-Fa-f]{1,16}$")
_RUNNING_UID = re.compile(r"^job-([0-9]{1,18})$")


def _query(printer: Printer, **filters: Any) -> HistoryQuery:
    return HistoryQuery(
        printer_ids=frozenset({printer.pk}), printer_id=printer.pk, **filters
    )


def _unix(value: str | None, name: str) -> datetime | None:
    if value in (None, ""):
        return None
    try:
        seconds = float(value)
        return datetime.fromtimestamp(seconds, tz=UTC)
    except (ValueError, OverflowError, OSError):
        raise HttpError(
            400, f"{name} must be a Unix time in seconds, not {value!r}"
        ) from None


def _seconds(iso: str | None) -> float | None:
    return datetime.fromisoformat(iso).timestamp() if iso else None


def _job(run: RunDict, on_disk: set[int]) -> dict[str, Any]:
    """One run in Moonraker's shape."""
    uid = f"{run['id']:06X}" if run["id"] is not None else f"job-{run['job']}"
    metadata: dict[str, Any] = {
        "size": run["size"],
        **{METADATA[k]: v for k, v in run["metadata"].items() if k in METADATA},
    }
    return {
        "job_id": uid,
        "user": run["user"],
        "filename": run["file"] or run["name"],
        "exists": run["job"] in on_disk,
        "status": STATUS[Outcome(run["outcome"])],
        "start_time": _seconds(run["started"]),
        "end_time": _seconds(run["finished"]),
        "print_duration": run["print_seconds"],
        "total_duration": run["print_seconds"],
        "filament_used": run["filament_used"] or 0.0,
        "metadata": metadata,
        "auxiliary_data": [],
    }


def _jobs(runs: list[RunDict]) -> list[dict[str, Any]]:
    # A file "exists" while its job's stored file is there (not removed by upkeep).
    on_disk = set(
        Job.objects.filter(
            pk__in=[run["job"] for run in runs], file_removed_at__isnull=True
        )
        .exclude(file="")
        .values_list("pk", flat=True)
    )
    return [_job(run, on_disk) for run in runs]


@dialect_route(router, "GET", "/server/history/list")
@moonraker_errors
def moonraker_history_list(
    request: HttpRequest, slug: str | None = None
) -> HttpResponse:
    """The printer's runs: `limit`, `start`, `since`, `before`, `order`."""
    printer = choose_printer(request, slug, Role.VIEWER)
    params = request.GET
    limit = parse_int(params.get("limit"), "limit", default=50)
    if limit > MAX_LIMIT:
        raise HttpError(400, f"limit must be at most {MAX_LIMIT}, not {limit}")
    start = parse_int(params.get("start"), "start", default=0)
    order = params.get("order") or "desc"
    if order not in ("asc", "desc"):
        raise HttpError(400, f"order must be asc or desc, not {order!r}")
    since = _unix(params.get("since"), "since")
    before = _unix(params.get("before"), "before")
    query = _query(printer, since=since, before=before, ascending=order == "asc")
    found = _jobs(page(query, limit=limit, offset=start).runs)
    return JsonResponse({"result": {"count": len(found), "jobs": found}})


@dialect_route(router, "GET", "/server/history/job")
@moonraker_errors
def moonraker_history_job(
    request: HttpRequest, slug: str | None = None
) -> HttpResponse:
    """One run by its `uid` (an entry's hex id, or `job-<id>` while it prints)."""
    printer = choose_printer(request, slug, Role.VIEWER)
    uid = (request.GET.get("uid") or "").strip()
    if not uid:
        raise HttpError(400, "uid is required: a job_id from server/history/list")
    item: HistoryEntry | Job | None = None
    if _ENTRY_UID.match(uid):
        item = HistoryEntry.objects.filter(pk=int(uid, 16), printer=printer).first()
    elif running := _RUNNING_UID.match(uid):
        number = int(running.group(1))
        item = (
            Job.objects.filter(pk=number, printer=printer, state__in=ACTIVE_STATES)
            .select_related("printer", "uploaded_by", "analysis")
            .defer("analysis__result")
            .first()
        )
        if item is None:  # it has ended since: its entry
            item = (
                HistoryEntry.objects.filter(job_number=number, printer=printer)
                .order_by("-started_at")
                .first()
            )
    if item is None:
        raise HttpError(404, f"no run {uid!r} in {printer.slug}'s history")
    return JsonResponse({"result": {"job": _jobs(as_dicts([item]))[0]}})


@dialect_route(router, "GET", "/server/history/totals")
@moonraker_errors
def moonraker_history_totals(
    request: HttpRequest, slug: str | None = None
) -> HttpResponse:
    """The printer's ended runs, counted."""
    printer = choose_printer(request, slug, Role.VIEWER)
    overall = totals(_query(printer))["overall"]
    return JsonResponse(
        {
            "result": {
                "job_totals": {
                    "total_jobs": overall["jobs"],
                    "total_time": overall["print_seconds"],
                    "total_print_time": overall["print_seconds"],
                    "total_filament_used": overall["filament_used"],
                    "longest_job": overall["longest_seconds"],
                    "longest_print": overall["longest_seconds"],
                },
                "auxiliary_totals": [],
            }
        }
    )
