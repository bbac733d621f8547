"""Printers whose worker fell silent: shown offline, their runs interrupted.

A worker renews its lease five times per `PRINTHOST_LEASE_SECONDS`; a lease that
ran out means its worker (or its whole worker host) stopped: killed, powered off,
or cut off from the database. The control plane's runhost looks every second
(`reap_silent_workers`) and, for each such printer, in one transaction that is
refused if the worker renewed meanwhile:

- the printer's state becomes `offline`, saying which host stopped answering;
- its running or paused job becomes `interrupted` at the line the database last
  heard of (saved once a second). The exact line is in the host's journal: the
  host's next worker corrects it when it starts (`spool.recover_interrupted`).

The lease itself is left as it is: the printer is handed to nobody. Only a worker
on the printer's own host may claim it (`Lease.claim`), and only once it holds
the port (`portlock`), so a host that was merely cut off and still drives the
printer cannot be raced; when it is back it renews its lease and writes what it
held, and its run goes on (`printers/worker/offline.py`).
"""

from __future__ import annotations

import logging

from django.db import transaction
from django.db.models.functions import Now
from django.utils import timezone

from jobs import history
from jobs.models import ACTIVE_STATES, Job
from printers import broadcast
from printers.models import Printer

logger = logging.getLogger("printhost.reaper")

#: In the message of a run interrupted here: the host's next worker looks for it.
LAST_SAVED = "as last saved; the exact line comes from the host's journal"


def reap_silent_workers() -> list[int]:
    """Mark printers whose lease ran out offline, and their runs interrupted.

    Returns the ids of the printers marked.
    """
    now = timezone.now()
    silent = (
        # The database's clock, which wrote the leases (printers/dbclock.py).
        Printer.objects.filter(lease_expires_at__lt=Now())
        .exclude(lease_owner="")
        .exclude(state=Printer.State.OFFLINE)
        .values_list("pk", "lease_owner", "lease_expires_at", "worker_host__name")
    )
    reaped = []
    for pk, owner, expires, host in silent:
        where = f"worker host {host}" if host else "its worker"
        message = (
            f"{where} stopped answering (its lease ran out at "
            f"{timezone.localtime(expires):%H:%M:%S})"
        )
        with transaction.atomic():
            marked = Printer.objects.filter(
                pk=pk, lease_owner=owner, lease_expires_at=expires
            ).update(state=Printer.State.OFFLINE, state_message=message)
            if not marked:
                continue  # the worker renewed meanwhile: it is alive
            jobs = list(Job.objects.filter(printer_id=pk, state__in=ACTIVE_STATES))
            for job in jobs:
                Job.objects.filter(pk=job.pk, state__in=ACTIVE_STATES).update(
                    state=Job.State.INTERRUPTED,
                    finished_at=now,
                    message=(
                        f"interrupted: {message} at line {job.lines_acked} of "
                        f"{job.line_count} {LAST_SAVED} when it is back. Not "
                        "restarted: resume it from there, or clear the bed and "
                        "print it again"
                    ),
                )
        logger.warning("printer %s: %s; %d run(s) interrupted", pk, message, len(jobs))
        publisher = broadcast.publisher()
        publisher.status(pk, {"state": Printer.State.OFFLINE, "state_message": message})
        for job in jobs:
            history.record_run(job.pk)
            publisher.job(job.pk)
        reaped.append(pk)
    return reaped
