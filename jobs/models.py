"""Jobs: a stored G-code file spooled on one printer, with its progress and outcome."""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path
from typing import TYPE_CHECKING, Any

from django.conf import settings
from django.db import models

from jobs import hostcache
from jobs.paths import inside
from printers.dbclock import shared_now
from printers.models import Printer

#: At most this many seconds of a saved progress's age bring `Job.timing` on: a
#: save is due every second, so a longer silence is a worker that cannot write.
PROGRESS_AGE_LIMIT = 5.0

if TYPE_CHECKING:
    from datetime import datetime


class FileAnalysis(models.Model):
    """What the analysis of one file (for one motion profile) found, or how far it is.

    Keyed by the file's SHA-256 and the profile's digest: the same file printed on
    printers with the same limits is analysed once. Celery runs it
    (`jobs.tasks.analyse_file`); the row, not the broker, is the truth: a task
    that finds the row done does nothing, and the sweep sends again what a dead
    worker left (`jobs.analysing.sweep`).
    """

    class State(models.TextChoices):
        PENDING = "pending", "waiting for a Celery worker"
        RUNNING = "running", "being analysed"
        DONE = "done", "done"
        FAILED = "failed", "failed"

    sha256 = models.CharField(max_length=64)
    profile = models.CharField(
        max_length=16, help_text="digest of the firmware and motion profile used"
    )
    firmware = models.CharField(max_length=16, default="marlin")
    settings = models.JSONField(
        default=dict, help_text="the limits and materials the analysis starts from"
    )
    state = models.CharField(
        max_length=16, choices=State.choices, default=State.PENDING
    )
    reason = models.TextField(blank=True, help_text="why it failed or is partial")
    result = models.JSONField(default=dict, blank=True)
    #: The figures lists and cards show (`analysing.summary_of`), without the
    #: timeline and layers that only a running job or the preview needs.
    summary = models.JSONField(default=dict, blank=True)
    attempts = models.PositiveIntegerField(default=0)
    worker = models.CharField(max_length=200, blank=True)
    sent_at = models.DateTimeField(
        null=True, blank=True, help_text="when a task was last handed to the broker"
    )
    bytes_done = models.BigIntegerField(default=0)
    created_at = models.DateTimeField(auto_now_add=True)
    started_at = models.DateTimeField(null=True, blank=True)
    heartbeat_at = models.DateTimeField(null=True, blank=True)
    finished_at = models.DateTimeField(null=True, blank=True)

    class Meta:
        verbose_name_plural = "file analyses"
        constraints = [
            models.UniqueConstraint(fields=["sha256", "profile"], name="analysis_key")
        ]
        indexes = [
            models.Index(fields=["state", "heartbeat_at"], name="analysis_state")
        ]

    def __str__(self) -> str:
        return f"analysis of {self.sha256[:12]} ({self.state})"

    def as_dict(self, *, size: int = 0) -> dict[str, Any]:
        """State and figures, as every client sees them under a job's `analysis`.

        `progress` is the share of the file (of *size* bytes) read so far, while the
        analysis runs.
        """
        running = self.state == self.State.RUNNING and size > 0
        return {
            "state": self.state,
            "reason": self.reason,
            "progress": round(100 * min(1, self.bytes_done / size), 1)
            if running
            else None,
            **self.summary,
        }


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

    class Kind(models.TextChoices):
        #: printhost streams the stored file line by line (the usual job).
        PRINT = "print", "print (streamed by printhost)"
        #: The printer prints `sd_name` from its own SD card; printhost watches.
        SD_PRINT = "sd_print", "print from the printer's SD card"
        #: printhost writes the stored file onto the printer's card as `sd_name`.
        SD_UPLOAD = "sd_upload", "copy to the printer's SD card"

    printer = models.ForeignKey(Printer, on_delete=models.CASCADE, related_name="jobs")
    name = models.CharField(max_length=255)
    kind = models.CharField(max_length=16, choices=Kind.choices, default=Kind.PRINT)
    file = models.CharField(
        max_length=500,
        blank=True,
        help_text="path under the job storage (empty for a print from the SD card)",
    )
    sd_name = models.CharField(
        max_length=100, blank=True, help_text="the file's name on the printer's SD card"
    )
    print_after = models.BooleanField(
        default=False, help_text="SD upload: print the file from the card once written"
    )
    size_bytes = models.BigIntegerField(default=0)
    line_count = models.BigIntegerField(default=0, help_text="commands to send")
    sha256 = models.CharField(max_length=64, blank=True)
    analysis = models.ForeignKey(
        FileAnalysis,
        on_delete=models.SET_NULL,
        null=True,
        blank=True,
        related_name="jobs",
    )
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
    #: When the worker saved lines_acked and bytes_acked (about once a second while
    #: printing): the estimate is made for that moment, then brought to now.
    progress_at = models.DateTimeField(null=True, blank=True)
    created_at = models.DateTimeField(auto_now_add=True)
    started_at = models.DateTimeField(null=True, blank=True)
    finished_at = models.DateTimeField(null=True, blank=True)
    #: A resumed run: the run it continues, the file's command it starts at and the
    #: commands sent before it (heat, home, move back, restore the modes).
    resume_of = models.ForeignKey(
        "self",
        on_delete=models.SET_NULL,
        null=True,
        blank=True,
        related_name="resumes",
        help_text="the interrupted, failed or aborted run this one continues",
    )
    start_line = models.BigIntegerField(
        default=0, help_text="the file's commands before this one are not sent"
    )
    start_offset = models.BigIntegerField(
        default=0, help_text="where the start line begins in the stored file (bytes)"
    )
    preamble = models.TextField(
        blank=True, help_text="commands sent before the file's lines (a resume)"
    )
    #: Objects (the analysis' names) the operator cancelled: their lines are skipped.
    cancelled_objects = models.JSONField(default=list, blank=True)
    #: A resume: the object streaming at `start_line` and the `M486 S` numbers the
    #: file named before it (`ObjectFilter.place`, from the plan).
    start_objects = models.JSONField(default=dict, blank=True)
    file_removed_at = models.DateTimeField(
        null=True,
        blank=True,
        help_text="when the upkeep removed the job's file (past its printer's "
        "job_file_days): the job stays as history but cannot be printed again",
    )

    class Meta:
        ordering = ["position", "id"]
        indexes = [
            # Used by the worker to claim the next job of its printer.
            models.Index(
                fields=["printer", "position", "id"],
                name="job_queued",
                condition=models.Q(state="queued"),
            ),
            # The farm's "last ended" of each printer; a printer's finished jobs.
            models.Index(fields=["printer", "finished_at"], name="job_finished"),
        ]

    def __str__(self) -> str:
        return f"{self.name} on {self.printer_id} ({self.state})"

    @property
    def is_resume(self) -> bool:
        """A resumed run: it starts with its plan's preamble, at `start_line`."""
        return bool(self.start_line or self.preamble)

    @property
    def path(self) -> Path:
        """Absolute path of the stored file (PathRefused if the row names one outside
        the job storage: a row is never trusted to stay in it). On a worker host,
        the fetched copy once its SHA-256 checks out (`jobs.hostcache`)."""
        stored = inside(Path(settings.JOB_STORAGE_DIR), self.file)
        return hostcache.local_path(stored, self.sha256)

    @property
    def on_sd_card(self) -> bool:
        """The job is about the printer's own SD card (printed from it, or copied to it)."""
        return self.kind != Job.Kind.PRINT

    @property
    def progress(self) -> float:
        """Share of the file's bytes acknowledged by the firmware, 0..1."""
        if self.size_bytes <= 0:
            return 0.0
        return min(1.0, self.bytes_acked / self.size_bytes)

    def elapsed_seconds(self) -> float | None:
        """Seconds since the job started (until it finished); None before it starts."""
        if self.started_at is None:
            return None
        end = self.finished_at or shared_now()
        return max(0.0, (end - self.started_at).total_seconds())

    def saved_moment(self, elapsed: float) -> tuple[float, float]:
        """When the progress this row holds was saved, while the job prints: the
        seconds the job had run then (both times stamped by the worker), and the
        seconds since (PROGRESS_AGE_LIMIT at most), by which the machine has moved
        on from its `lines_acked`. (*elapsed*, 0) when paused, finished or never
        saved."""
        saved, started = self.progress_at, self.started_at
        if self.state != self.State.PRINTING or saved is None or started is None:
            return elapsed, 0.0
        since = (shared_now() - saved).total_seconds()
        then = max(0.0, (saved - started).total_seconds())
        return then, min(max(0.0, since), PROGRESS_AGE_LIMIT)

    def remaining_seconds(self) -> float | None:
        """A linear guess from elapsed time and progress, while the job runs."""
        elapsed, share = self.elapsed_seconds(), self.progress
        if elapsed is None or self.finished_at is not None or not 0 < share < 1:
            return None
        then, since = self.saved_moment(elapsed)
        return max(0.0, then / share * (1 - share) - since)

    def timing(self) -> dict[str, Any]:
        """Remaining time, end time, layer and filament so far, by the file's analysis
        (`jobs.eta`) while the job runs; the linear guess when there is none. Both
        are made at the saved progress's moment and brought to now (`saved_moment`):
        an old line with the time elapsed now would add up to a second."""
        elapsed, linear = self.elapsed_seconds(), self.remaining_seconds()
        out: dict[str, Any] = {
            "eta": None if linear is None else round(linear, 1),
            "eta_origin": None if linear is None else "linear",
            "ends_at": None,
            "time_progress": None,
            "layer": None,
            "layers": None,
            "filament_used": None,
        }
        running = self.state in ACTIVE_STATES and elapsed is not None
        analysed = None
        if running and self.analysis_id:
            from jobs.analysing import analysis_of

            analysed = analysis_of(self)
        if analysed is not None:
            from jobs.eta import estimate

            then, since = self.saved_moment(elapsed)
            found = estimate(analysed, line=self.lines_acked, elapsed=then)
            out.update(
                eta=round(max(0.0, found.remaining - since), 1),
                eta_origin=found.origin,
                time_progress=found.progress,
                layer=found.layer,
                layers=found.layers,
                filament_used=found.filament_used,
            )
        if running and out["eta"] is not None:
            out["ends_at"] = (shared_now() + timedelta(seconds=out["eta"])).isoformat()
        return out

    def as_dict(self) -> dict[str, Any]:
        """The job as every client sees it (API, websockets): one shape everywhere.

        `progress` is the percentage of the file's bytes the firmware acknowledged;
        `elapsed` and `eta` are seconds (None when unknown); `eta_origin` says how
        the ETA was made ("mixed-analysis": the analysis corrected by the measured
        pace; "linear": elapsed over bytes); `analysis` is the file's analysis
        (None for a print from the SD card); `objects` are the file's objects,
        each with `cancelled` (printhost/api/objects.py).
        """
        elapsed = self.elapsed_seconds()
        timing = self.timing()

        def when(value: datetime | None) -> str | None:
            return value.isoformat() if value else None

        return {
            "id": self.pk,
            "printer": self.printer.slug,
            "name": self.name,
            "kind": self.kind,
            "sd_name": self.sd_name,
            "state": self.state,
            "message": self.message,
            "size": self.size_bytes,
            "lines": self.line_count,
            "sha256": self.sha256,
            "position": self.position,
            "origin": self.origin,
            "lines_sent": self.lines_sent,
            "lines_acked": self.lines_acked,
            "bytes_acked": self.bytes_acked,
            "progress": round(self.progress * 100, 2),
            "created": when(self.created_at),
            "started": when(self.started_at),
            "finished": when(self.finished_at),
            "elapsed": None if elapsed is None else round(elapsed, 1),
            **timing,
            "analysis": self.analysis_dict(),
            "objects": [
                {"name": name, "cancelled": name in self.cancelled_objects}
                for name in self.objects_list()
            ],
        }

    def objects_list(self) -> list[str]:
        """The file's objects as its analysis names them ([] before it finishes)."""
        if not self.analysis_id or self.analysis is None:
            return []
        return list(self.analysis.summary.get("objects") or [])

    def analysis_dict(self) -> dict[str, Any] | None:
        """The file's analysis with the job's own thumbnail addresses."""
        if not self.analysis_id or self.analysis is None:
            return None
        data = self.analysis.as_dict(size=self.size_bytes)
        base = f"/printer/thumbnail/{self.printer.slug}/{self.pk}/"
        data["thumbnails"] = [
            {**picture, "url": base + picture["name"]}
            for picture in data.get("thumbnails", [])
        ]
        return data


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
#: The jobs whose files a worker host fetches, and may read from the control
#: plane: the ones it will print or is printing (printers/fetcher.py).
HOST_FILE_STATES = frozenset({Job.State.QUEUED, *ACTIVE_STATES})
#: A printer's active jobs in this order: the first is its running job.
RUNNING_ORDER = ("started_at", "pk")


def running_job(printer_id: int) -> Job | None:
    """The printer's printing or paused job, if any (the worker runs one at a time)."""
    return (
        Job.objects.filter(printer_id=printer_id, state__in=ACTIVE_STATES)
        .select_related("printer", "analysis")
        .defer("analysis__result")
        .order_by(*RUNNING_ORDER)
        .first()
    )


# A model kept in its own module: imported here so Django finds it.
from jobs.farm.models import FarmJob  # noqa: E402, F401
from jobs.history import HistoryEntry  # noqa: E402, F401
from jobs.plans import ResumePlan  # noqa: E402, F401
from jobs.upload_sessions import Upload  # noqa: E402, F401
