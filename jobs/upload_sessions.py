"""An unfinished upload: the row of a partial file that grows by chunks until it
becomes a job (`jobs/uploads.py` runs the sessions)."""

from __future__ import annotations

from pathlib import Path

from django.conf import settings
from django.db import models

from jobs.paths import inside
from printers.models import Printer


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
        """Absolute path of the partial file (inside the job storage, or PathRefused)."""
        return inside(Path(settings.JOB_STORAGE_DIR), self.path, hidden=True)
