"""A printer's job list as the API gives it: its open jobs, then its newest finished.

Job rows are never deleted (they are the printer's history), so a list of every
job grows with each print: a farm printer's reached thousands of rows, all read
and sent on each poll of the UI's queue. The list holds every job that is not
finished (stored, queued, printing, paused) in queue order, then the newest
finished ones, newest first, as many as asked (`FINISHED_SHOWN` unless told);
older runs are the history's (`/printer/history`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from django.db.models import F

from jobs.models import FINISHED_STATES, Job

if TYPE_CHECKING:
    from printers.models import Printer

__all__ = ["FINISHED_MOST", "FINISHED_SHOWN", "printer_jobs"]

#: Finished jobs listed after the open ones when the caller does not say.
FINISHED_SHOWN = 50
#: The most finished jobs one list gives.
FINISHED_MOST = 500


def printer_jobs(printer: Printer, *, finished: int = FINISHED_SHOWN) -> list[Job]:
    """The printer's open jobs in queue order, then its *finished* (0 to
    FINISHED_MOST, as the API checks) newest finished ones, newest end first."""
    jobs = (
        Job.objects.filter(printer=printer)
        .select_related("printer", "analysis")
        .defer("analysis__result")
    )
    open_jobs = jobs.exclude(state__in=FINISHED_STATES).order_by("position", "id")
    newest = F("finished_at").desc(nulls_last=True)
    done = jobs.filter(state__in=FINISHED_STATES).order_by(newest, "-id")
    return [*open_jobs, *done[:finished]]
