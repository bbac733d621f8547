"""What the seed API shows of printers and jobs: the shapes its answers share."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from jobs.models import ACTIVE_STATES, RUNNING_ORDER, Job
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
        .order_by(*RUNNING_ORDER)
        .values_list("printer_id", "state")
    )
    states: dict[int, str] = {}
    for printer_id, state in rows:
        states.setdefault(printer_id, state)
    return states


#: The printer columns `printer_entries` reads (a list polled often reads only these).
ENTRY_FIELDS = ("name", "slug", "state", "enabled")
#: The printer columns `printer_state` reads (with those of its jobs' `as_dict`).
STATE_FIELDS = (
    "name", "slug", "state", "state_message", "firmware", "firmware_name",
    "temperatures", "machine_status",
)  # fmt: skip


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


def running_and_queued(printer: Printer) -> tuple[Job | None, list[Job]]:
    """The printer's running job (as `jobs.models.running_job` finds it) and its
    queue in order, in one query: hosts ask a printer's state every second or two.

    Each job's `printer` is *printer* itself, not a copy read again with it.
    """
    rows = list(
        Job.objects.filter(
            printer=printer, state__in=[*ACTIVE_STATES, Job.State.QUEUED]
        )
        .select_related("analysis")
        .defer("analysis__result")
        .order_by(*RUNNING_ORDER)
    )
    for job in rows:
        job.printer = printer
    active = next((job for job in rows if job.state in ACTIVE_STATES), None)
    queue = sorted(
        (job for job in rows if job.state == Job.State.QUEUED),
        key=lambda job: (job.position, job.pk),  # Job's own ordering
    )
    return active, queue


def printer_state(printer: Printer) -> dict[str, Any]:
    """Everything a host shows about a printer at a glance."""
    active, queue = running_and_queued(printer)
    status = printer.machine_status or {}
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
