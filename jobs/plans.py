"""Resume plans: where a stopped print would start again, and what is sent first.

A plan is made for a run that ended before its last line (interrupted, failed or
aborted), at a line (by default the last one the firmware acknowledged) or at a
layer's first line. A Celery task (`jobs.tasks.plan_resume`) reads the file up to
that line to rebuild the machine's state (`jobs.resume.state`) and writes the
preamble (`jobs.resume.preamble`); the operator reads it, then starts the plan,
which queues a new run of the same file linked to the old one (`Job.resume_of`).
"""

from __future__ import annotations

from typing import Any

from django.conf import settings
from django.db import models


class ResumePlan(models.Model):
    """One proposal to resume a run, from making to use."""

    class State(models.TextChoices):
        PENDING = "pending", "reading the file"
        READY = "ready", "ready to start"
        FAILED = "failed", "could not be made"
        STARTED = "started", "started"

    job = models.ForeignKey("jobs.Job", on_delete=models.CASCADE, related_name="plans")
    line = models.BigIntegerField(help_text="the file's command the run starts at")
    layer = models.IntegerField(
        null=True, blank=True, help_text="the layer (0-based) chosen, if any"
    )
    state = models.CharField(
        max_length=16, choices=State.choices, default=State.PENDING
    )
    reason = models.TextField(blank=True)
    preamble = models.TextField(blank=True)
    #: The state rebuilt at the line (`MachineState.as_dict`).
    machine = models.JSONField(default=dict, blank=True)
    created_by = models.ForeignKey(
        settings.AUTH_USER_MODEL,
        on_delete=models.SET_NULL,
        null=True,
        blank=True,
        related_name="+",
    )
    origin = models.CharField(max_length=100, blank=True)
    created_at = models.DateTimeField(auto_now_add=True)
    resumed = models.ForeignKey(
        "jobs.Job",
        on_delete=models.SET_NULL,
        null=True,
        blank=True,
        related_name="+",
        help_text="the run this plan started",
    )

    def __str__(self) -> str:
        return f"resume of job {self.job_id} at line {self.line} ({self.state})"

    def as_dict(self) -> dict[str, Any]:
        """The plan as the API and the UI show it."""
        return {
            "id": self.pk,
            "job": self.job_id,
            "line": self.line,
            "layer": self.layer,
            "state": self.state,
            "reason": self.reason,
            "preamble": self.preamble.splitlines(),
            "machine": self.machine,
            "created": self.created_at.isoformat() if self.created_at else None,
            "resumed_job": self.resumed_id,
        }
