"""The audit log: who sent which command, started, paused or aborted which job."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from printhost.models import AuditEntry

if TYPE_CHECKING:
    from jobs.models import Job
    from printers.models import Printer
    from printhost.access import Caller

log = logging.getLogger("printhost.audit")


def record(
    caller: Caller,
    action: str,
    *,
    printer: Printer | None = None,
    job: Job | None = None,
    detail: str = "",
) -> AuditEntry:
    """Write one entry (and a log line) for an action a caller asked for."""
    user = caller.user if caller.authenticated else None
    entry = AuditEntry.objects.create(
        user=user,
        client=caller.client,
        origin=caller.origin,
        action=action,
        printer=printer,
        job=job,
        detail=detail[:2000],
    )
    log.info(
        "%s %s%s%s%s",
        caller.origin,
        action,
        f" printer={printer.slug}" if printer else "",
        f" job={job.pk}" if job else "",
        f" {detail[:200]!r}" if detail else "",
    )
    return entry
