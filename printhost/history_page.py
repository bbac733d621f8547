"""The history page's first render: the runs and totals the filters name.

The page's form is a plain GET form (it works without its script); the script
(`static/printhost/history.js`) keeps running runs live through the same API
(`/printer/history`). The form's date range is inclusive: "until" a day is
`before` the next day's midnight.
"""

from __future__ import annotations

from dataclasses import replace
from datetime import date, datetime, timedelta
from typing import TYPE_CHECKING, Any
from urllib.parse import urlencode

from django.utils import timezone
from ninja.errors import HttpError

from jobs.history import Outcome
from jobs.history_query import GROUPS, page, totals
from printhost.access import Forbidden
from printhost.api.print_history import query_from
from printhost.models import Role

if TYPE_CHECKING:
    from django.http import QueryDict

    from jobs.history import RunDict
    from printhost.access import Caller

#: Runs shown by the first render (the script loads more on demand).
PAGE_RUNS = 50
FILTERS = ("printer", "user", "outcome", "since", "until", "group")


def api_params(form: dict[str, str]) -> dict[str, str]:
    """The page's filters as the API's: `until` (inclusive day) -> `before`."""
    params = {k: form[k] for k in ("printer", "user", "outcome", "since") if form[k]}
    until = form["until"]
    if until:
        try:
            params["before"] = (
                date.fromisoformat(until) + timedelta(days=1)
            ).isoformat()
        except (ValueError, OverflowError):  # 9999-12-31 has no next day
            params["before"] = until  # refused with the API's own message
    return params


def history_context(caller: Caller, data: QueryDict) -> dict[str, Any]:
    """What the page shows: filters, totals, runs, the CSV link, or the problem."""
    form = {name: data.get(name, "").strip() for name in FILTERS}
    group = form["group"] if form["group"] in GROUPS else "printer"
    form["group"] = group
    params = api_params(form)
    context: dict[str, Any] = {
        "form": form,
        "printers": caller.printers(Role.VIEWER),
        "outcomes": [*Outcome.choices, ("resumed", "resumed")],
        "groups": list(GROUPS),
        "query": urlencode(params),
        "csv": "/printer/history?" + urlencode({**params, "format": "csv"}),
        "problem": "",
        "runs": [],
        "count": 0,
        "totals": None,
    }
    try:
        query = query_from(caller, params)
    except (HttpError, Forbidden) as error:
        context["problem"] = str(error)
        return context
    found = page(query, limit=PAGE_RUNS)
    figures = totals(replace(query, outcome=None), group)
    context.update(
        runs=[run_view(run) for run in found.runs], count=found.count, totals=figures
    )
    return context


def run_view(run: RunDict) -> dict[str, Any]:
    """A run with the words the page shows (history.js `runCard` writes the same)."""
    from printhost.pages import clock, metres

    started = datetime.fromisoformat(run["started"])
    finished = run["finished"]
    layers = f"{run['layer']} / {run['layers']}" if run["layers"] else "—"
    return {
        **run,
        "started_text": timezone.localtime(started).strftime("%Y-%m-%d %H:%M"),
        "finished_text": timezone.localtime(datetime.fromisoformat(finished)).strftime(
            "%H:%M"
        )
        if finished
        else "",
        "duration": clock(run["print_seconds"]),
        "filament": metres(run["filament_used"]),
        "layers_text": layers,
        "outcome_label": Outcome(run["outcome"]).label,
    }
