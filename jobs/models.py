"""Jobs: a stored G-code file spooled on one printer, with its progress and outcome."""

from __future__ import annotations

from pathlib import Path

from django.conf import settings
from django.db import models

from printers.models import Printer


class Job(models.Model):
    """A file on disk waiting, streaming or done on one printer (the stream queue)."""

    class State(models.TextChoices):
        STORED = "stored", "stored (not queued)"
        QUEUED = "queued", "queued"
        PRINTING = "printing", "printing"
        PAUSED = "paused", "paused"
        COMPLETED = "completed", "completed"
        ABORTED = "aborted", "aborted"
        FAILED = "failed", "failed"
        INTERRUPTED = "interrupted", "interrupted"

    printer = models.ForeignKey(Printer, on_delete=models.CASCADE, related_name="jobs")
    name = models.CharField(max_length=255)
    file = models.CharField(max_length=500, help_text="path under the job storage")
    size_bytes = models.BigIntegerField(default=0)
    line_count = models.BigIntegerField(default=0, help_text="commands to send")
    sha256 = models.CharField(max_length=64, blank=True)
    position = models.BigIntegerField(default=0, help_text="queue order, lowest first")
    origin = models.CharField(max_length=100, blank=True)
    uploaded_by = models.ForeignKey(
        settings.AUTH_USER_MODEL,
        on_delete=models.SET_NULL,
        null=True,
        blank=True,
        related_name="+",
    )
    state = models.CharField(max_length=16, choices=State.choices, default=State.QUEUED)
    message = models.TextField(blank=True)
    lines_sent = models.BigIntegerField(default=0)
    lines_acked = models.BigIntegerField(default=0)
    bytes_acked = models.BigIntegerField(default=0)
    created_at = models.DateTimeField(auto_now_add=True)
    started_at = models.DateTimeField(null=True, blank=True)
    finished_at = models.DateTimeField(null=True, blank=True)

    class Meta:
        ordering = ["position", "id"]
        indexes = [
            # Used by the worker to claim the next job of its printer.
            models.Index(
                fields=["printer", "position", "id"],
                name="job_queued",
                condition=models.Q(state="queued"),
            )
        ]

    def __str__(self) -> str:
        return f"{self.name} on {self.printer_id} ({self.state})"

    @property
    def path(self) -> Path:
        """Absolute path of the stored file."""
        return Path(settings.JOB_STORAGE_DIR) / self.file

    @property
    def progress(self) -> float:
        """Share of the file's bytes acknowledged by the firmware, 0..1."""
        if self.size_bytes <= 0:
            return 0.0
        return min(1.0, self.bytes_acked / self.size_bytes)


FINISHED_STATES = frozenset(
    {
        Job.State.COMPLETED,
        Job.State.ABORTED,
        Job.State.FAILED,
        Job.State.INTERRUPTED,
    }
)
#: States in which a worker owns the job; after a crash they become INTERRUPTED.
ACTIVE_STATES = frozenset({Job.State.PRINTING, Job.State.PAUSED})
