"""Upkeep of the printers' tables, run by Celery beat (`printers/tasks.py`).

- `trim_response_logs`: each printer's response log down to its newest
  `response_log_limit` lines.
- `prune_temperature_samples`: the chart's samples older than
  PRINTHOST_TEMPERATURE_KEEP_HOURS.

The printer's worker only writes these rows; deleting them is done here, away from
its loop. Rows go in bounded batches (`BATCH_ROWS` per statement, each its own
short transaction), so a big table never holds SQLite's write lock for long and
the workers' writes slip in between. Each function returns what it removed and
logs one line.
"""

from __future__ import annotations

import logging
from datetime import datetime, timedelta
from typing import TYPE_CHECKING, Any

from django.conf import settings
from django.db.models import Max
from django.utils import timezone

from printers.models import Printer, ResponseLine, TemperatureSample

if TYPE_CHECKING:
    from django.db.models import QuerySet

logger = logging.getLogger("printhost.upkeep")

#: Rows deleted by one statement at most.
BATCH_ROWS = 2000


def trim_response_logs(*, batch: int = BATCH_ROWS) -> dict[str, int]:
    """Delete each printer's response lines beyond its `response_log_limit`.

    The newest `response_log_limit` lines (by id) are kept: a line whose id is more
    than the limit below the printer's highest id goes. Returns {"lines": n}.
    """
    removed = 0
    for printer_id, limit in Printer.objects.values_list("pk", "response_log_limit"):
        removed += _trim_log(printer_id, limit, batch)
    logger.info(
        "upkeep: %d response line(s) past their printer's limit removed", removed
    )
    return {"lines": removed}


def _trim_log(printer_id: int, limit: int, batch: int) -> int:
    lines = ResponseLine.objects.filter(printer_id=printer_id)
    top = lines.aggregate(top=Max("seq"))["top"]
    if top is None or top - limit <= 0:
        return 0
    return _delete_below(lines, "seq", top - limit, batch, inclusive=True)


def prune_temperature_samples(
    *, now: datetime | None = None, batch: int = BATCH_ROWS
) -> dict[str, int]:
    """Delete temperature samples older than PRINTHOST_TEMPERATURE_KEEP_HOURS.

    A sample exactly that old is kept. Returns {"samples": n}.
    """
    keep = timedelta(hours=settings.PRINTHOST_TEMPERATURE_KEEP_HOURS)
    cutoff = (now or timezone.now()) - keep
    removed = 0
    for printer_id in Printer.objects.values_list("pk", flat=True):
        samples = TemperatureSample.objects.filter(printer_id=printer_id)
        removed += _delete_below(samples, "time", cutoff, batch, inclusive=False)
    logger.info(
        "upkeep: %d temperature sample(s) older than %g h removed",
        removed,
        settings.PRINTHOST_TEMPERATURE_KEEP_HOURS,
    )
    return {"samples": removed}


def _delete_below(
    rows: QuerySet[Any], field: str, bound: Any, batch: int, *, inclusive: bool
) -> int:
    """Delete *rows* whose *field* is below *bound* (or equal, when *inclusive*),
    oldest first, at most about *batch* rows per statement; returns how many."""
    below = rows.filter(**{f"{field}__{'lte' if inclusive else 'lt'}": bound})
    removed = 0
    while True:
        # The value of the batch-th oldest row bounds this statement (an index
        # read); fewer rows than a batch left: the rest goes at once.
        ordered = below.order_by(field).values_list(field, flat=True)
        step = list(ordered[batch - 1 : batch])
        chunk = below.filter(**{f"{field}__lte": step[0]}) if step else below
        deleted, _ = chunk.delete()
        removed += deleted
        if not step or not deleted:
            return removed
