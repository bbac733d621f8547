"""The farm job: a stored file waiting for any printer that meets its requirements.

States (`FarmJob.State`):

| state | set by | next |
|---|---|---|
| waiting | the upload (`jobs.farm.storing.store_farm_upload`) | assigned (the dispatcher's claim), cancelled |
| assigned | the dispatcher, in the transaction that queues the printer's `Job` | — (it follows its Job) |
| cancelled | an operator (`jobs.farm.storing.cancel`) | — |

While it waits, `reason` says why, in words a person acts on; once assigned,
`job` and `printer` say where it went and the job's own state tells the rest.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from django.conf import settings
from django.db import models

from jobs.farm.requirements import Requirements
from jobs.paths import inside

if TYPE_CHECKING:
    from datetime import datetime


class FarmJob(models.Model):
    """One file for the farm queue, its requirements, and where it went."""

    class State(models.TextChoices):
        WAITING = "waiting", "waiting for a printer"
        ASSIGNED = "assigned", "given to a printer"
        CANCELLED = "cancelled", "cancelled"

    name = models.CharField(max_length=255)
    file = models.CharField(
        max_length=500,
        blank=True,
        help_text="path under the job storage (farm/...); emptied once the printer's "
        "job holds the file",
    )
    size_bytes = models.BigIntegerField(default=0)
    line_count = models.BigIntegerField(default=0, help_text="commands to send")
    sha256 = models.CharField(max_length=64)
    longest_command = models.PositiveIntegerField(
        default=0, help_text="characters of the file's longest command"
    )
    analysis = models.ForeignKey(
        "jobs.FileAnalysis",
        on_delete=models.SET_NULL,
        null=True,
        blank=True,
        related_name="+",
        help_text="the analysis whose bounding box routes the job",
    )

    # -- what it asks of a printer (empty = anything) ------------------------------
    material = models.CharField(max_length=32, blank=True)
    colour = models.CharField(max_length=32, blank=True)
    nozzle_diameter = models.FloatField(null=True, blank=True, help_text="mm")
    profile = models.CharField(max_length=100, blank=True)
    tags = models.JSONField(default=list, blank=True)

    # -- queue order: priority (highest first), deadline (soonest first), age ------
    priority = models.IntegerField(default=0, help_text="higher goes first")
    deadline = models.DateTimeField(
        null=True, blank=True, help_text="among equal priorities, soonest first"
    )

    state = models.CharField(
        max_length=16, choices=State.choices, default=State.WAITING
    )
    reason = models.TextField(blank=True, help_text="why it still waits")
    job = models.ForeignKey(
        "jobs.Job",
        on_delete=models.SET_NULL,
        null=True,
        blank=True,
        related_name="+",
        help_text="the printer's job it became",
    )
    printer = models.ForeignKey(
        "printers.Printer",
        on_delete=models.SET_NULL,
        null=True,
        blank=True,
        related_name="+",
    )
    origin = models.CharField(max_length=100, blank=True)
    uploaded_by = models.ForeignKey(
        settings.AUTH_USER_MODEL,
        on_delete=models.SET_NULL,
        null=True,
        blank=True,
        related_name="+",
    )
    created_at = models.DateTimeField(auto_now_add=True)
    assigned_at = models.DateTimeField(null=True, blank=True)
    cancelled_at = models.DateTimeField(null=True, blank=True)

    class Meta:
        ordering = [
            "-priority",
            models.F("deadline").asc(nulls_last=True),
            "created_at",
            "id",
        ]
        indexes = [
            # Used by the dispatcher's pass: the waiting jobs in queue order.
            models.Index(
                fields=["-priority", "deadline", "created_at", "id"],
                name="farmjob_queue",
                condition=models.Q(state="waiting"),
            )
        ]

    def __str__(self) -> str:
        return f"farm job {self.pk} {self.name} ({self.state})"

    @property
    def path(self) -> Path:
        """Absolute path of the stored file (PathRefused if the row names one outside
        the job storage)."""
        return inside(Path(settings.JOB_STORAGE_DIR), self.file)

    @property
    def requirements(self) -> Requirements:
        return Requirements(
            material=self.material,
            colour=self.colour,
            nozzle=self.nozzle_diameter,
            profile=self.profile,
            tags=tuple(self.tags or ()),
        )

    def as_dict(self, *, would_go_to: str | None = None) -> dict[str, Any]:
        """The farm job as the API and the farm view show it.

        `state` is the farm's (waiting, assigned, cancelled); `job` is the printer's
        job once assigned, with its own state; `would_go_to` is the printer the
        matcher would choose now (waiting jobs, when asked for).
        """

        def when(value: datetime | None) -> str | None:
            return value.isoformat() if value else None

        analysis = self.analysis
        return {
            "id": self.pk,
            "name": self.name,
            "state": self.state,
            "reason": self.reason,
            "requirements": self.requirements.as_dict(),
            "asks": self.requirements.describe(),
            "priority": self.priority,
            "deadline": when(self.deadline),
            "size": self.size_bytes,
            "lines": self.line_count,
            "sha256": self.sha256,
            "analysis": None
            if analysis is None
            else {
                "state": analysis.state,
                "bbox": analysis.summary.get("bbox"),
                "estimated_seconds": analysis.summary.get("estimated_seconds"),
                "reason": analysis.reason,
            },
            "printer": self.printer.slug if self.printer_id and self.printer else None,
            "job": None
            if not self.job_id or self.job is None
            else {"id": self.job_id, "state": self.job.state},
            "would_go_to": would_go_to,
            "origin": self.origin,
            "created": when(self.created_at),
            "assigned": when(self.assigned_at),
            "cancelled": when(self.cancelled_at),
        }
