"""The live feed as clients read it: groups, the per-client cursor, the database reads.

The database stays the truth; the feed only says "something new was written"
(`printers.broadcast` sends it: the worker with Redis, a relay without).

- **Groups**: one per printer, `printer.<id>`. Events are `lines` / `state` /
  `temperatures` / `job` (the JSON clients receive, minus the slug).
- **`LineCursor`** (sans-IO): decides per client which lines to send, so a reconnect
  with the last id seen gets every line once: no gap, no duplicate.
- **Readers** (sync; call them through `database_sync_to_async`): pages of lines after
  an id, the log's bounds, a printer's snapshot for a client's `hello`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from django.db.models import Max, Min

from jobs.models import Job, running_job
from printers.models import Printer, ResponseLine

if TYPE_CHECKING:
    from collections.abc import Iterable
    from datetime import datetime

#: Every client also re-reads the log this often (s): the channel layer may drop a
#: message (a Redis restart, a full channel); the database never does.
RECONCILE_SECONDS = 5.0
#: Lines read from the database per query (catch-up pages, relay polls).
PAGE_LINES = 2000
#: The non-maskable kind: no filter hides it (errors, resets, printhost's notes).
NON_MASKABLE = 8


#: One response line as clients receive it: id, time, text, type.
Line = dict[str, Any]


def group_for(printer_id: int) -> str:
    """The channel-layer group of one printer's feed."""
    return f"printer.{printer_id}"


def line_dict(seq: int, when: datetime, text: str, kind: int) -> Line:
    """One response line as clients receive it (Repetier's fields)."""
    return {"id": seq, "time": when.isoformat(), "text": text, "type": kind}


# -- the cursor (sans-IO) -------------------------------------------------------------


@dataclass
class LineCursor:
    """Where one client is in a printer's response log.

    Feed it batches (live ones, or pages read from the database): `gap` says which ids
    are missing before a batch, `take` drops what the client already has and what its
    filter hides, `truncated` handles lines pruned before the client could read them.
    """

    last: int
    filter: int = 0

    def gap(self, lines: list[Line]) -> tuple[int, int] | None:
        """The ids (first, last) missing between the client and *lines*, if any."""
        fresh = [line["id"] for line in lines if line["id"] > self.last]
        if fresh and min(fresh) > self.last + 1:
            return self.last + 1, min(fresh) - 1
        return None

    def take(self, lines: Iterable[Line]) -> list[Line]:
        """The lines to send, in id order; the cursor moves past every id seen."""
        hidden = self.filter & ~NON_MASKABLE
        out: list[Line] = []
        for line in sorted(lines, key=lambda item: item["id"]):
            if line["id"] <= self.last:
                continue
            self.last = line["id"]
            if not line["type"] & hidden:
                out.append(line)
        return out

    def truncated(self, first_kept: int | None) -> dict[str, Any] | None:
        """A notice if lines after `last` were pruned before *first_kept*; skips to it."""
        if first_kept is None or first_kept <= self.last + 1:
            return None
        self.last = first_kept - 1
        return {"type": "truncated", "first": first_kept}


# -- reading the database (sync; call through database_sync_to_async) ----------------


def lines_after(printer_id: int, last: int, upto: int | None = None) -> list[Line]:
    """One page of lines with id > *last* (and <= *upto*), oldest first."""
    rows = ResponseLine.objects.filter(printer_id=printer_id, seq__gt=last)
    if upto is not None:
        rows = rows.filter(seq__lte=upto)
    values = rows.order_by("seq").values_list("seq", "time", "text", "kind")
    return [line_dict(*row) for row in values[:PAGE_LINES]]


def log_bounds(printer_id: int) -> tuple[int, int]:
    """(oldest id kept, newest id) of a printer's log; (0, 0) when empty."""
    bounds = ResponseLine.objects.filter(printer_id=printer_id).aggregate(
        first=Min("seq"), last=Max("seq")
    )
    return bounds["first"] or 0, bounds["last"] or 0


def state_of(printer: Printer) -> dict[str, Any]:
    return {
        "state": printer.state,
        "message": printer.state_message,
        "firmware_name": printer.firmware_name,
        "machine_status": printer.machine_status,
        "sd_card": printer.sd_card,
    }


def current_job(printer_id: int) -> Job | None:
    return running_job(printer_id)


def snapshot(printer_id: int) -> dict[str, Any]:
    """What a client gets on subscribing: state, temperatures, job, log bounds."""
    printer = Printer.objects.get(pk=printer_id)
    job = current_job(printer_id)
    first, last = log_bounds(printer_id)
    return {
        **state_of(printer),
        "temperatures": printer.temperatures,
        "job": job.as_dict() if job else None,
        "first": first,
        "last": last,
    }
