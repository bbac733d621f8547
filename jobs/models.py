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


class Upload(models.Model):
    """An unfinished upload: a partial file that grows by chunks until it becomes a job.

    Both the seed's `job?a=create` + `append` and the resumable `/printer/upload/`
    sessions use it. The bytes on disk are the truth: the offset is always the partial
    file's size, so a dropped connection can never make the two disagree.
    """

    id = models.CharField(primary_key=True, max_length=32, editable=False)
    printer = models.ForeignKey(Printer, on_delete=models.CASCADE, related_name="+")
    user = models.ForeignKey(
        settings.AUTH_USER_MODEL,
        on_delete=models.SET_NULL,
        null=True,
        blank=True,
        related_name="+",
    )
    name = models.CharField(max_length=255)
    size = models.BigIntegerField(default=0, help_text="announced size; 0 = unknown")
    sha256_expected = models.CharField(max_length=64, blank=True)
    path = models.CharField(max_length=500, help_text="partial file under the storage")
    options = models.JSONField(default=dict, blank=True)
    created_at = models.DateTimeField(auto_now_add=True)
    updated_at = models.DateTimeField(auto_now=True)

    class Meta:
        # Used by the cleanup of abandoned sessions.
        indexes = [models.Index(fields=["updated_at"], name="upload_updated")]

    def __str__(self) -> str:
        return f"upload {self.id} of {self.name} to {self.printer_id}"

    @property
    def partial_path(self) -> Path:
        """Absolute path of the partial file."""
        return Path(settings.JOB_STORAGE_DIR) / self.path
