"""Fixtures of the history tests: a small farm, and runs ended as a worker ends them.

`Farm.run` claims a job with the worker's own `spool.claim_next` and ends it with
`spool.finish` (or `fail_job`, `recover_interrupted`), the functions a worker calls:
no worker loop, but the same database writes.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
from django.contrib.auth import get_user_model
from django.test import Client
from django.utils import timezone

from jobs import analysis_task
from jobs.models import Job
from jobs.services import enqueue_job, reprint
from printers.models import Printer
from printers.streaming import Stream, StreamType
from printers.worker import spool
from printhost.access import issue_key
from printhost.models import PrinterRole, Role

if TYPE_CHECKING:
    from django.contrib.auth.models import AbstractBaseUser

#: A real PrusaSlicer slice: 10 layers, analysed for filament by line.
FLAT_BOX = (
    Path(__file__).resolve().parents[1] / "data" / "prusaslicer-2.5_flat-box.gcode"
)


@dataclass
class Farm:
    """Printers p and q; alice operates p, bob operates q, vera views p."""

    p: Printer
    q: Printer
    users: dict[str, AbstractBaseUser]
    keys: dict[str, str]
    source: Path

    def client(self, who: str) -> Client:
        """A client that sends *who*'s API key with every request."""
        return Client(headers={"X-Api-Key": self.keys[who]})

    def job(self, printer: Printer, user: str, *, name: str = "box.gcode") -> Job:
        """A queued job of the flat box, analysed (as the Celery task would)."""
        job = enqueue_job(
            printer,
            self.source,
            name=name,
            origin=f"http:{user} key",
            user=self.users[user],
        )
        analysis_task.run(job.analysis_id)
        return Job.objects.get(pk=job.pk)

    def start(self, job: Job, *, minutes_ago: float) -> Job:
        """Claim *job* as the worker does, started *minutes_ago* minutes ago."""
        Job.objects.filter(printer=job.printer, state=Job.State.QUEUED).exclude(
            pk=job.pk
        ).update(state=Job.State.STORED)
        claimed = spool.claim_next(job.printer_id)
        assert claimed is not None and claimed.pk == job.pk
        started = timezone.now() - timedelta(minutes=minutes_ago)
        Job.objects.filter(pk=job.pk).update(started_at=started)
        return Job.objects.get(pk=job.pk)

    def end(
        self, job: Job, outcome: str, *, acked: int | None = None, message: str = ""
    ) -> Job:
        """End a started run with `spool.finish`, at *acked* lines (all by default)."""
        stream = Stream(StreamType.SD_FILE_STREAM, [], name=job.name, ref=job.pk)
        stream.outcome = outcome
        stream.message = message
        stream.done = stream.reached = job.line_count if acked is None else acked
        spool.finish(stream)
        return Job.objects.get(pk=job.pk)

    def run(
        self,
        printer: Printer,
        user: str,
        outcome: str,
        *,
        minutes: float = 30,
        acked: int | None = None,
        message: str = "",
        name: str = "box.gcode",
    ) -> Job:
        """A whole run: queued, claimed *minutes* ago, ended now with *outcome*."""
        job = self.start(self.job(printer, user, name=name), minutes_ago=minutes)
        return self.end(job, outcome, acked=acked, message=message)

    def resume(self, job: Job, line: int, *, minutes: float = 10) -> Job:
        """A resumed run of *job* from *line*, started (as the resume would queue it)."""
        again = reprint(job, origin=job.origin, user=job.uploaded_by)
        Job.objects.filter(pk=again.pk).update(resume_of=job, start_line=line)
        analysis_task.run(again.analysis_id)
        return self.start(Job.objects.get(pk=again.pk), minutes_ago=minutes)


@pytest.fixture
def farm(db: None, storage: Path) -> Farm:
    p = Printer.objects.create(name="Prusa P", slug="p", port="/dev/null", state="idle")
    q = Printer.objects.create(name="Prusa Q", slug="q", port="/dev/null", state="idle")
    users: dict[str, AbstractBaseUser] = {}
    keys: dict[str, str] = {}
    for name, role, printer in (
        ("alice", Role.OPERATOR, p),
        ("bob", Role.OPERATOR, q),
        ("vera", Role.VIEWER, p),
        ("root", Role.ADMIN, None),
    ):
        user = get_user_model().objects.create_user(name, password=name)
        PrinterRole.objects.create(user=user, printer=printer, role=role)
        users[name] = user
        keys[name] = issue_key(user, "history")[1]
    return Farm(p, q, users, keys, FLAT_BOX)
