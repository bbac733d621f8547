"""What the seed API shows of printers and jobs: the shapes its answers share."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from jobs.models import ACTIVE_STATES, Job, running_job
from printers.models import Printer
from printhost.clients import ONLINE_STATES

if TYPE_CHECKING:
    from collections.abc import Iterable


def _job_word(printer: Printer, active: str | None) -> str:
    """The seed's `job` field: none, printing, paused or waitstart (*active*: the
    state of the printer's running job, None without one)."""
    if printer.state == Printer.State.WAITSTART:
        return "waitstart"
    if active is None:
        return "none"
    return "paused" if active == Job.State.PAUSED else "printing"


def running_job_states(printer_ids: Iterable[int]) -> dict[int, str]:
    """Each printer's running (printing or paused) job's state, in one query (a list
    of printers asked one query a printer: 50 ms for 32 of them)."""
    rows = (
        Job.objects.filter(printer_id__in=list(printer_ids), state__in=ACTIVE_STATES)
        .order_by("started_at", "pk")
        .values_list("printer_id", "state")
    )
    states: dict[int, str] = {}
    for printer_id, state in rows:
        states.setdefault(printer_id, state)
    return states


def printer_entries(printers: Iterable[Printer]) -> list[dict[str, Any]]:
    """The seed's list entry of each printer, plus `state` and `active` (enabled)."""
    printers = list(printers)
    running = running_job_states(p.pk for p in printers)
    return [
        {
            "name": printer.name,
            "slug": printer.slug,
            "online": 1 if printer.state in ONLINE_STATES else 0,
            "active": printer.enabled,
            "job": _job_word(printer, running.get(printer.pk)),
            "state": printer.state,
        }
        for printer in printers
    ]


def printer_state(printer: Printer) -> dict[str, Any]:
    """Everything a host shows about a printer at a glance."""
    active = running_job(printer.pk)
    status = printer.machine_status or {}
    queue = (
        Job.objects.filter(printer=printer, state=Job.State.QUEUED)
        .select_related("printer", "analysis")
        .defer("analysis__result")
    )
    return {
        "slug": printer.slug,
        "name": printer.name,
        "state": printer.state,
        "message": printer.state_message,
        "online": printer.state in ONLINE_STATES,
        "waitstart": printer.state == Printer.State.WAITSTART,
        "firmware": printer.firmware,
        "firmware_name": printer.firmware_name,
        "temperatures": printer.temperatures or {},
        "position": {k: v for k, v in status.items() if k not in ("state", "prompt")},
        "machine_state": status.get("state", ""),
        # The firmware's host prompt: {"message", "choices", "answerable"} or None.
        "prompt": status.get("prompt"),
        "job": active.as_dict() if active else None,
        "queue": [job.as_dict() for job in queue],
    }
