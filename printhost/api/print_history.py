"""Print history in printhost's own calls: the runs, totals, and a CSV export.

    GET /printer/history            runs, newest first: {"count", "limit", "offset",
                                    "runs": [...]}; `format=csv` for a spreadsheet
    GET /printer/history/totals     ended runs counted: {"group", "since", "before",
                                    "overall", "groups": [...]}

Filters, all optional: `printer` (slug), `user` (user name), `outcome`
(completed, aborted, failed, interrupted, in_progress or resumed), `since` and
`before` (ISO 8601 dates or times on the run's start; a date is its midnight in
the server's time zone; `since` included, `before` excluded), `order` (desc or
asc), `limit` (0..1000, default 50) and `offset`. Totals take `group` (printer,
user or file) and the printer, user and period filters.

Anyone with a role may read the history of the printers they may view (a key
bound to a printer: that printer's); runs of a deleted printer only a caller with
a role on every printer. The answers use the `{"error", "data"}` envelope.
"""

from __future__ import annotations

import csv
import io
from datetime import date, datetime, time
from typing import TYPE_CHECKING

from asgiref.sync import sync_to_async
from django.http import HttpRequest, HttpResponse, StreamingHttpResponse
from django.http.response import HttpResponseBase  # noqa: TC002 (ninja reads hints)
from django.utils import timezone
from ninja import Router
from ninja.errors import HttpError

from jobs.history_query import (
    GROUPS,
    OUTCOME_FILTERS,
    HistoryQuery,
    ended,
    iter_runs,
    page,
    running,
    totals,
)
from printers.models import Printer
from printhost.access import Forbidden
from printhost.api.common import caller_of, envelope, parse_int
from printhost.models import Role

if TYPE_CHECKING:
    from collections.abc import AsyncIterator, Iterable, Iterator, Mapping

    from jobs.history import RunDict
    from printhost.access import Caller

router = Router(tags=["print history"])

#: The most runs one list call returns.
MAX_LIMIT = 1000
#: The years a filter's time may name.
FIRST_YEAR, LAST_YEAR = 1900, 2200
#: The most runs one CSV export holds: narrow the period past that.
MAX_CSV_ROWS = 100_000
CSV_COLUMNS = (
    "id", "job", "printer", "name", "file", "sha256", "kind", "user", "origin",
    "started", "finished", "outcome", "message", "resumed_from_job",
    "resumed_from_line", "print_seconds", "filament_used_mm", "layer", "layers",
    "lines_acked", "lines",
)  # fmt: skip


def parse_moment(value: str | None, name: str) -> datetime | None:
    """An ISO 8601 date or date and time (the server's time zone when none is
    given), or None when empty; 400 saying what was wrong otherwise."""
    if value in (None, ""):
        return None
    try:
        moment = datetime.fromisoformat(value)
    except ValueError:
        try:
            moment = datetime.combine(date.fromisoformat(value), time())
        except ValueError:
            raise HttpError(
                400,
                f"{name} must be an ISO 8601 date or time (2026-11-24 or "
                f"2026-11-24T08:30:00Z), not {value!r}",
            ) from None
    if not FIRST_YEAR <= moment.year <= LAST_YEAR:
        # Out there, the time in UTC the database compares falls off the calendar.
        raise HttpError(
            400, f"{name} must fall in the years {FIRST_YEAR} to {LAST_YEAR}, not "
            f"{value!r}",
        )  # fmt: skip
    if timezone.is_naive(moment):
        moment = timezone.make_aware(moment)
    return moment


def query_of(request: HttpRequest) -> HistoryQuery:
    """The history the caller may read, narrowed by the request's filters."""
    return query_from(caller_of(request), request.GET)


def query_from(caller: Caller, params: Mapping[str, str]) -> HistoryQuery:
    """The history *caller* may read, narrowed by *params* (the API's filters).

    404 for an unknown printer, 403 for one the caller may not view, 400 for a
    filter that makes no sense.
    """
    readable = frozenset(p.pk for p in caller.printers(Role.VIEWER))
    orphans = caller.bound_printer_id is None and caller.can(None, Role.VIEWER)
    if not readable and not orphans:
        raise Forbidden("you hold no role on any printer")
    printer_id = None
    if slug := params.get("printer", ""):
        printer = Printer.objects.filter(slug=slug).first()
        if printer is None:
            raise HttpError(404, f"Unknown printer {slug!r}")
        caller.require(printer, Role.VIEWER)
        printer_id = printer.pk
    outcome = params.get("outcome") or None
    if outcome is not None and outcome not in OUTCOME_FILTERS:
        raise HttpError(
            400, f"outcome must be one of {', '.join(OUTCOME_FILTERS)}, not {outcome!r}"
        )
    order = params.get("order") or "desc"
    if order not in ("asc", "desc"):
        raise HttpError(400, f"order must be asc or desc, not {order!r}")
    since = parse_moment(params.get("since"), "since")
    before = parse_moment(params.get("before"), "before")
    if since is not None and before is not None and since >= before:
        raise HttpError(400, "before must be later than since")
    return HistoryQuery(
        # A caller who may read the runs of deleted printers holds a role on every
        # printer: no list to match (an OR with it made the database sort every
        # run, 200 ms a page at 100,000 runs against 5 ms).
        printer_ids=None if orphans else readable,
        orphans=orphans,
        printer_id=printer_id,
        user=params.get("user") or None,
        outcome=outcome,
        since=since,
        before=before,
        ascending=order == "asc",
    )


@router.get("/printer/history", summary="Print history: every run of every job")
def history_list(request: HttpRequest) -> HttpResponseBase:
    """Runs (ended and running), filtered; `format=csv` exports them all."""
    query = query_of(request)
    shape = request.GET.get("format") or "json"
    if shape == "csv":
        return _csv(query)
    if shape != "json":
        raise HttpError(400, f"format must be json or csv, not {shape!r}")
    limit = parse_int(request.GET.get("limit"), "limit", default=50)
    if limit > MAX_LIMIT:
        raise HttpError(400, f"limit must be at most {MAX_LIMIT}, not {limit}")
    offset = parse_int(request.GET.get("offset"), "offset", default=0)
    found = page(query, limit=limit, offset=offset)
    return envelope(
        {"count": found.count, "limit": limit, "offset": offset, "runs": found.runs}
    )


@router.get("/printer/history/totals", summary="Print history: totals over a period")
def history_totals(request: HttpRequest) -> HttpResponse:
    """Ended runs counted (jobs, completed, success rate, print hours, filament),
    overall and by `group` (printer, user or file)."""
    query = query_of(request)
    if query.outcome is not None:
        raise HttpError(400, "totals count every outcome: leave outcome out")
    group = request.GET.get("group") or None
    if group is not None and group not in GROUPS:
        raise HttpError(400, f"group must be one of {', '.join(GROUPS)}, not {group!r}")
    found = totals(query, group)
    found["since"] = query.since.isoformat() if query.since else None
    found["before"] = query.before.isoformat() if query.before else None
    return envelope(found)


def _csv(query: HistoryQuery) -> StreamingHttpResponse:
    """The runs as CSV, written as they are read, a batch at a time: a whole
    export held at once took 4 s and 200 MB a request, asked by any viewer."""
    count = ended(query).count() + len(running(query))
    if count > MAX_CSV_ROWS:
        raise HttpError(
            400,
            f"{count} runs match, more than {MAX_CSV_ROWS} in one export: "
            "narrow the period (since, before) or the printer",
        )
    batches = _csv_batches(query)
    # Under ASGI a synchronous iterator is read whole before it is sent: the
    # batches are pulled one by one from the thread the database reads run on.
    take = sync_to_async(lambda: next(batches, None))

    async def stream() -> AsyncIterator[bytes]:
        while (batch := await take()) is not None:
            yield batch

    stamp = timezone.localtime().strftime("%Y%m%d-%H%M")
    response = StreamingHttpResponse(stream(), content_type="text/csv; charset=utf-8")
    response["Content-Disposition"] = (
        f'attachment; filename="printhost-history-{stamp}.csv"'
    )
    return response


def _csv_batches(query: HistoryQuery, rows: int = 500) -> Iterator[bytes]:
    out = io.StringIO()
    writer = csv.writer(out)
    writer.writerow(CSV_COLUMNS)
    for number, run in enumerate(iter_runs(query), start=1):
        writer.writerow(_csv_row(run))
        if number % rows == 0:
            yield out.getvalue().encode()
            out.seek(0)
            out.truncate()
    yield out.getvalue().encode()


def _csv_row(run: RunDict) -> Iterable[object]:
    resumed = run["resumed_from"]
    values: dict[str, object] = {
        **run,
        "resumed_from_job": resumed["job"] if resumed else "",
        "resumed_from_line": resumed["line"] if resumed else "",
        "filament_used_mm": run["filament_used"],
    }
    return [_cell(values.get(column)) for column in CSV_COLUMNS]


def _cell(value: object) -> object:
    """A value as a spreadsheet reads it: empty for None, and text that a
    spreadsheet would run as a formula (a file named `=cmd|...`) kept as text."""
    if value is None:
        return ""
    if isinstance(value, str) and value[:1] in ("=", "+", "-", "@", "\t", "\r"):
        return "'" + value
    return value
