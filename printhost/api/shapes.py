"""What the seed API shows of printers and jobs: the shapes its answers share."""

from __future__ import annotations

from typing import Any

from jobs.models import Job, running_job
from printers.models import Printer
from printhost.clients import ONLINE_STATES


def _job_word(printer: Printer, active: Job | None) -> str:
    """The seed's `job` field: none, printing, paused or waitstart."""
    if printer.state == Printer.State.WAITSTART:
        return "waitstart"
    if active is None:
        return "none"
    return "paused" if active.state == Job.State.PAUSED else "printing"


def printer_entry(printer: Printer) -> dict[str, Any]:
    """The seed's list entry, plus `state` and `active` (enabled)."""
    active = running_job(printer.pk)
    return {
        "name": printer.name,
        "slug": printer.slug,
        "online": 1 if printer.state in ONLINE_STATES else 0,
        "active": printer.enabled,
        "job": _job_word(printer, active),
        "state": printer.state,
    }


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
