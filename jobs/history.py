"""Print history: one durable entry per run of a job, written when the run ends.

A run is a Job row that a worker claimed (each reprint and each resume is a new
row; the admin's "queue again" runs the same row again). When the run ends, the
worker's end-of-run functions (`printers.worker.spool`: `finish`,
`recover_interrupted`, `fail_job`; a print from the SD card ends through `finish`
too) call `record_run`, which copies what the history needs out of the Job row:
the row itself may be deleted later (`a=delete`, the admin) and the entry stays.

Rules:

- H1. One entry per run: (job number, start time) is unique, so recording the same
  run twice (a retried end, a worker's recovery after it already ended) changes
  the entry, never adds one.
- H2. Figures are computed once, at the end, from the file's analysis at the last
  acknowledged line: filament used (mm, this run's share: a resumed run counts
  from its start line), the layer reached and the file's layers. No analysis (a
  print from the SD card, an analysis that failed): unknown (None), never 0.
- H3. A copy to the SD card prints nothing: it has no entry.
- H4. Print time is the wall-clock time from start to end (pauses included:
  printhost does not time pauses).
- H5. A running run has no entry yet: lists show it from its Job row
  (`running_dict`), with its figures so far.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypedDict

from django.conf import settings
from django.db import models
from django.db.models import F

from printers.dbclock import shared_now

if TYPE_CHECKING:
    from datetime import datetime

    from jobs.models import Job


class Outcome(models.TextChoices):
    """How a run ended (the Job's finished states), or that it still runs."""

    COMPLETED = "completed", "completed"
    ABORTED = "aborted", "aborted"
    FAILED = "failed", "failed"
    INTERRUPTED = "interrupted", "interrupted"
    #: Only in lists (H5): never stored.
    IN_PROGRESS = "in_progress", "in progress"


#: The analysis summary's figures kept with an entry (Moonraker's `metadata`).
METADATA_KEYS = (
    "estimated_seconds",
    "filament_total",
    "filament_weight_g",
    "layers",
    "layer_height",
    "first_layer_height",
    "object_height",
    "slicer",
    "slicer_version",
    "material",
)


class ResumedFrom(TypedDict):
    job: int
    line: int
    exists: bool


class RunLink(TypedDict):
    job: int
    exists: bool


class RunDict(TypedDict):
    """One run as every printhost client sees it (API, CSV, the history page)."""

    id: int | None
    job: int
    job_exists: bool
    printer: str
    printer_name: str
    name: str
    file: str
    sha256: str
    kind: str
    size: int
    user: str | None
    origin: str
    started: str
    finished: str | None
    outcome: str
    message: str
    resumed_from: ResumedFrom | None
    #: The runs that resumed this one.
    resumed_by: list[RunLink]
    print_seconds: float
    filament_used: float | None
    layer: int | None
    layers: int | None
    lines_acked: int
    lines: int
    start_line: int
    #: The analysis' figures of the file (`METADATA_KEYS`), as the run began.
    metadata: dict[str, Any]


class HistoryEntry(models.Model):
    """One finished run of a job, kept after the job is gone."""

    #: The Job row's id (not a foreign key: the row may be deleted).
    job_number = models.BigIntegerField(help_text="the job's id (it may be deleted)")
    printer = models.ForeignKey(
        "printers.Printer",
        on_delete=models.SET_NULL,
        null=True,
        blank=True,
        related_name="+",
    )
    printer_name = models.CharField(max_length=100, blank=True)
    printer_slug = models.CharField(max_length=100, blank=True)
    name = models.CharField(max_length=255)
    file = models.CharField(
        max_length=500, blank=True, help_text="the stored file's path (empty: SD card)"
    )
    sha256 = models.CharField(max_length=64, blank=True)
    kind = models.CharField(max_length=16, default="print")
    size_bytes = models.BigIntegerField(default=0)
    user = models.ForeignKey(
        settings.AUTH_USER_MODEL,
        on_delete=models.SET_NULL,
        null=True,
        blank=True,
        related_name="+",
    )
    user_name = models.CharField(
        max_length=150, blank=True, help_text="who started it (kept if the user goes)"
    )
    origin = models.CharField(max_length=100, blank=True, help_text="from which client")
    started_at = models.DateTimeField()
    finished_at = models.DateTimeField()
    outcome = models.CharField(max_length=16, choices=Outcome.choices)
    message = models.TextField(blank=True)
    #: A resumed run: the job it continues and the file's command it started at.
    resumed_from = models.BigIntegerField(null=True, blank=True)
    start_line = models.BigIntegerField(default=0)
    lines_acked = models.BigIntegerField(default=0)
    line_count = models.BigIntegerField(default=0)
    print_seconds = models.FloatField(default=0.0)
    filament_used = models.FloatField(
        null=True, blank=True, help_text="mm; empty when the file was not analysed"
    )
    layer = models.IntegerField(null=True, blank=True, help_text="the layer reached")
    layers = models.IntegerField(null=True, blank=True, help_text="the file's layers")
    metadata = models.JSONField(default=dict, blank=True)

    class Meta:
        verbose_name_plural = "history entries"
        ordering = ["-started_at", "-id"]
        constraints = [
            # H1: a run recorded twice is one entry.
            models.UniqueConstraint(
                fields=["job_number", "started_at"], name="history_one_per_run"
            )
        ]
        indexes = [
            # Used by the history list and totals of one printer over a period.
            models.Index(fields=["printer", "started_at"], name="history_printer"),
            # Used by the list and totals of every printer over a period.
            models.Index(fields=["started_at"], name="history_started"),
            # Used to show which runs resumed an entry ("resumed by #Y").
            models.Index(
                fields=["resumed_from"],
                name="history_resumed",
                condition=models.Q(resumed_from__isnull=False),
            ),
        ]

    def __str__(self) -> str:
        return f"{self.name} on {self.printer_slug} ({self.outcome})"

    @property
    def uid(self) -> str:
        """Moonraker's `job_id`: the entry's id as six hex digits."""
        return f"{self.pk:06X}"

    def as_dict(
        self, *, existing: set[int] | frozenset[int], resumed_by: list[RunLink]
    ) -> RunDict:
        """The entry; *existing* holds the job numbers whose Job row still exists."""
        resumed: ResumedFrom | None = None
        if self.resumed_from is not None:
            resumed = {
                "job": self.resumed_from,
                "line": self.start_line,
                "exists": self.resumed_from in existing,
            }
        return {
            "id": self.pk,
            "job": self.job_number,
            "job_exists": self.job_number in existing,
            "printer": self.printer_slug,
            "printer_name": self.printer_name,
            "name": self.name,
            "file": self.file.rsplit("/", 1)[-1],
            "sha256": self.sha256,
            "kind": self.kind,
            "size": self.size_bytes,
            "user": self.user_name or None,
            "origin": self.origin,
            "started": self.started_at.isoformat(),
            "finished": self.finished_at.isoformat(),
            "outcome": self.outcome,
            "message": self.message,
            "resumed_from": resumed,
            "resumed_by": resumed_by,
            "print_seconds": round(self.print_seconds, 1),
            "filament_used": self.filament_used,
            "layer": self.layer,
            "layers": self.layers,
            "lines_acked": self.lines_acked,
            "lines": self.line_count,
            "start_line": self.start_line,
            "metadata": self.metadata,
        }


@dataclass(frozen=True, slots=True)
class Figures:
    """What a run did, by its file's analysis (H2): None when not analysed."""

    filament_used: float | None = None
    layer: int | None = None
    layers: int | None = None


def figures_of(job: Job) -> Figures:
    """Filament used by this run and the layer it reached (H2).

    Uses the analysis the process already parsed (`analysing.analysis_of` keeps a
    few): a running job's broadcasts have read it, so the end of a run reads no
    more than one row.
    """
    if not job.analysis_id:
        return Figures()
    from jobs.analysing import analysis_of

    analysed = analysis_of(job)
    if analysed is None:
        return Figures()
    reached = max(job.lines_acked, job.start_line)
    used = analysed.filament_at(reached) - analysed.filament_at(job.start_line)
    layers = len(analysed.layers)
    layer = analysed.layer_at(reached) + 1 if layers and reached > 0 else 0
    return Figures(
        filament_used=round(max(0.0, used), 1),
        layer=max(0, layer) if layers else None,
        layers=layers or None,
    )


def _metadata(job: Job) -> dict[str, Any]:
    summary = job.analysis.summary if job.analysis_id and job.analysis else {}
    return {key: summary[key] for key in METADATA_KEYS if key in summary}


def forget_run(job_id: object) -> int:
    """Remove the entry of *job_id*'s current run: it was taken for ended
    (`printers.reaper`) but goes on; it is written again when it really ends."""
    from jobs.models import Job

    started = Job.objects.filter(pk=job_id).values_list("started_at", flat=True)
    return HistoryEntry.objects.filter(
        job_number=job_id, started_at__in=started
    ).delete()[0]


def record_run(job_id: object) -> HistoryEntry | None:
    """Write (or rewrite, H1) the history entry of *job_id*'s run, now ended.

    *job_id* is the Job's id (a worker's stream carries it as its `ref`).

    1. Read the Job row with its printer, uploader's name and analysis (not the
       analysis' result column, unless `analysis_of` has not read it in this
       process).
    2. Skip it if it never started, still runs, or copied a file to the SD card (H3).
    3. Work out the figures (H2) and the print time (H4).
    4. Insert the entry, or update the one this run already has.
    """
    from jobs.models import FINISHED_STATES, Job

    # The uploader's name only: a worker host's database role reads no more of
    # auth_user (printers/host_role.py).
    job = (
        Job.objects.select_related("printer", "analysis")
        .annotate(uploader_name=F("uploaded_by__username"))
        .filter(pk=job_id)
        .first()
    )
    if job is None or job.started_at is None or job.state not in FINISHED_STATES:
        return None
    if job.kind == Job.Kind.SD_UPLOAD:
        return None
    finished = job.finished_at or shared_now()
    figures = figures_of(job)
    entry, _ = HistoryEntry.objects.update_or_create(
        job_number=job.pk,
        started_at=job.started_at,
        defaults={
            "printer": job.printer,
            "printer_name": job.printer.name,
            "printer_slug": job.printer.slug,
            "name": job.name,
            "file": job.file,
            "sha256": job.sha256,
            "kind": job.kind,
            "size_bytes": job.size_bytes,
            "user_id": job.uploaded_by_id,
            "user_name": job.uploader_name or "",
            "origin": job.origin,
            "finished_at": finished,
            "outcome": job.state,
            "message": job.message,
            "resumed_from": job.resume_of_id,
            "start_line": job.start_line,
            "lines_acked": job.lines_acked,
            "line_count": job.line_count,
            "print_seconds": _seconds(job.started_at, finished),
            "filament_used": figures.filament_used,
            "layer": figures.layer,
            "layers": figures.layers,
            "metadata": _metadata(job),
        },
    )
    return entry


def _seconds(start: datetime, end: datetime) -> float:
    return max(0.0, (end - start).total_seconds())


def running_dict(job: Job, *, existing: set[int] | frozenset[int]) -> RunDict:
    """A run still printing or paused (H5), from its Job row, figures so far."""
    now = shared_now()
    started = job.started_at or now
    figures = figures_of(job)
    user = job.uploaded_by
    resumed: ResumedFrom | None = None
    if job.resume_of_id is not None:
        resumed = {
            "job": job.resume_of_id,
            "line": job.start_line,
            "exists": job.resume_of_id in existing,
        }
    return {
        "id": None,
        "job": job.pk,
        "job_exists": True,
        "printer": job.printer.slug,
        "printer_name": job.printer.name,
        "name": job.name,
        "file": job.file.rsplit("/", 1)[-1],
        "sha256": job.sha256,
        "kind": job.kind,
        "size": job.size_bytes,
        "user": user.get_username() if user is not None else None,
        "origin": job.origin,
        "started": started.isoformat(),
        "finished": None,
        "outcome": Outcome.IN_PROGRESS,
        "message": job.message,
        "resumed_from": resumed,
        "resumed_by": [],
        "print_seconds": round(_seconds(started, now), 1),
        "filament_used": figures.filament_used,
        "layer": figures.layer,
        "layers": figures.layers,
        "lines_acked": job.lines_acked,
        "lines": job.line_count,
        "start_line": job.start_line,
        "metadata": _metadata(job),
    }
