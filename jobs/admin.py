"""Jobs in the Django admin: list, filter, search and act on them."""

from __future__ import annotations

from typing import TYPE_CHECKING

from django.contrib import admin, messages

from jobs import analysing
from jobs.commands import request_action
from jobs.history import HistoryEntry
from jobs.models import ACTIVE_STATES, FarmJob, FileAnalysis, Job
from jobs.services import delete_job_file
from printers.doorbell import ring_at_commit
from printers.models import Printer

if TYPE_CHECKING:
    from django.db.models import QuerySet
    from django.http import HttpRequest
from printhost.access import admin_caller
from printhost.audit import record


@admin.register(Job)
class JobAdmin(admin.ModelAdmin):
    list_display = [
        "id",
        "name",
        "printer",
        "kind",
        "sd_name",
        "state",
        "progress_percent",
        "analysis_state",
        "lines_acked",
        "line_count",
        "created_at",
        "finished_at",
    ]
    list_filter = ["state", "kind", "printer", "created_at"]
    search_fields = ["name", "sd_name", "sha256", "origin", "uploaded_by__username"]
    date_hierarchy = "created_at"
    readonly_fields = [
        "kind",
        "sd_name",
        "file",
        "size_bytes",
        "line_count",
        "sha256",
        "lines_sent",
        "lines_acked",
        "bytes_acked",
        "started_at",
        "finished_at",
        "file_removed_at",
        "state",
        "message",
        "analysis",
    ]
    list_select_related = ["printer", "analysis"]
    actions = ["abort", "requeue", "mark_bed_clear", "delete_with_files"]

    @admin.display(description="progress")
    def progress_percent(self, job: Job) -> str:
        return f"{job.progress * 100:.1f} %"

    @admin.display(description="analysis")
    def analysis_state(self, job: Job) -> str:
        analysis = job.analysis
        if analysis is None:
            return "-"
        if analysis.state == FileAnalysis.State.DONE:
            return _duration(analysis.summary.get("estimated_seconds"))
        return analysis.get_state_display()

    @admin.action(description="Abort the running job", permissions=["change"])
    def abort(self, request: HttpRequest, queryset: QuerySet[Job]) -> None:
        caller = admin_caller(request)
        for job in queryset.filter(state__in=ACTIVE_STATES):
            request_action(job.printer, "abort", origin=caller.origin)
            record(caller, "abort", printer=job.printer, job=job)

    @admin.action(description="Queue again", permissions=["change"])
    def requeue(self, request: HttpRequest, queryset: QuerySet[Job]) -> None:
        caller = admin_caller(request)
        gone = queryset.filter(file_removed_at__isnull=False).count()
        queryset = queryset.filter(file_removed_at__isnull=True)
        printers: set[int] = set()
        for job in queryset.exclude(state__in=ACTIVE_STATES):
            record(caller, "requeue", printer=job.printer, job=job)
            printers.add(job.printer_id)
        if gone:
            messages.warning(
                request,
                f"{gone} job(s) kept as history: their files were removed after "
                "their printer's job_file_days; upload the files again",
            )
        # The whole file again, a resumed run too: its preamble goes back to the
        # height it once stopped at, over a bed now to be cleared.
        count = queryset.exclude(state__in=ACTIVE_STATES).update(
            state=Job.State.QUEUED,
            lines_sent=0,
            lines_acked=0,
            bytes_acked=0,
            progress_at=None,
            message="",
            started_at=None,
            finished_at=None,
            start_line=0,
            start_offset=0,
            preamble="",
            start_objects={},
        )
        for printer_id in printers:
            ring_at_commit(printer_id)
        messages.info(request, f"{count} job(s) queued again")

    @admin.action(
        description="The bed is clear: their printers start the next job",
        permissions=["change"],
    )
    def mark_bed_clear(self, request: HttpRequest, queryset: QuerySet[Job]) -> None:
        caller = admin_caller(request)
        printers = {job.printer for job in queryset.select_related("printer")}
        waiting = [p for p in printers if p.state == Printer.State.WAITSTART]
        for printer in waiting:
            request_action(printer, "bed_clear", origin=caller.origin)
            record(caller, "bed_clear", printer=printer)
        messages.info(request, f"asked {len(waiting)} waiting printer(s) to start")

    @admin.action(description="Delete with their files", permissions=["delete"])
    def delete_with_files(self, request: HttpRequest, queryset: QuerySet[Job]) -> None:
        busy = queryset.filter(state__in=ACTIVE_STATES).count()
        caller = admin_caller(request)
        for job in queryset.exclude(state__in=ACTIVE_STATES):
            record(caller, "delete", printer=job.printer, detail=job.name)
            delete_job_file(job)
            job.delete()
        if busy:
            messages.warning(request, f"{busy} running job(s) kept: abort them first")


def _duration(seconds: float | None) -> str:
    if seconds is None:
        return "done"
    minutes, _ = divmod(int(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes:02d} min" if hours else f"{minutes} min"


@admin.register(FileAnalysis)
class FileAnalysisAdmin(admin.ModelAdmin):
    """What the Celery worker found in each file, and analyses that failed."""

    list_display = [
        "id",
        "sha256_short",
        "state",
        "estimated",
        "attempts",
        "reason",
        "created_at",
        "finished_at",
    ]
    list_filter = ["state", "firmware", "created_at"]
    search_fields = ["sha256", "reason", "jobs__name"]
    readonly_fields = [
        "sha256", "profile", "firmware", "settings", "state", "reason", "summary",
        "attempts", "worker", "bytes_done", "sent_at", "created_at", "started_at",
        "heartbeat_at", "finished_at",
    ]  # fmt: skip
    exclude = ["result"]
    actions = ["analyse_again"]

    @admin.display(description="file")
    def sha256_short(self, analysis: FileAnalysis) -> str:
        names = list(analysis.jobs.values_list("name", flat=True)[:1])
        return f"{names[0] if names else '?'} ({analysis.sha256[:12]})"

    @admin.display(description="estimate")
    def estimated(self, analysis: FileAnalysis) -> str:
        if analysis.state != FileAnalysis.State.DONE:
            return "-"
        return _duration(analysis.summary.get("estimated_seconds"))

    @admin.action(description="Analyse again", permissions=["change"])
    def analyse_again(
        self, request: HttpRequest, queryset: QuerySet[FileAnalysis]
    ) -> None:
        again = list(
            queryset.exclude(state=FileAnalysis.State.RUNNING).values_list(
                "pk", flat=True
            )
        )
        FileAnalysis.objects.filter(pk__in=again).update(
            state=FileAnalysis.State.PENDING, worker="", reason="", sent_at=None,
            attempts=0,
        )  # fmt: skip
        for pk in again:
            analysing.send(pk)
        messages.info(request, f"{len(again)} analysis(es) sent to the Celery worker")

    def has_add_permission(self, request: HttpRequest) -> bool:
        return False


@admin.register(HistoryEntry)
class HistoryEntryAdmin(admin.ModelAdmin):
    """Every ended run, read-only: the history is a record, not something to edit."""

    list_display = [
        "id",
        "job_number",
        "name",
        "printer_slug",
        "user_name",
        "outcome",
        "started_at",
        "finished_at",
        "duration",
        "filament_m",
        "layers_reached",
    ]
    list_filter = ["outcome", "printer", "user", "kind", "started_at"]
    search_fields = ["name", "sha256", "printer_slug", "user_name", "origin", "message"]
    date_hierarchy = "started_at"
    list_select_related = ["printer"]

    def has_add_permission(self, request: HttpRequest) -> bool:
        return False

    def has_change_permission(
        self, request: HttpRequest, obj: HistoryEntry | None = None
    ) -> bool:
        return False

    def has_delete_permission(
        self, request: HttpRequest, obj: HistoryEntry | None = None
    ) -> bool:
        return False

    @admin.display(description="print time", ordering="print_seconds")
    def duration(self, entry: HistoryEntry) -> str:
        return _duration(entry.print_seconds)

    @admin.display(description="filament", ordering="filament_used")
    def filament_m(self, entry: HistoryEntry) -> str:
        if entry.filament_used is None:
            return "-"
        return f"{entry.filament_used / 1000:.2f} m"

    @admin.display(description="layers")
    def layers_reached(self, entry: HistoryEntry) -> str:
        return f"{entry.layer} / {entry.layers}" if entry.layers else "-"


@admin.register(FarmJob)
class FarmJobAdmin(admin.ModelAdmin):
    """The farm queue: requirements and order may be edited while a job waits; what
    the dispatcher writes (state, reason, where it went) is read-only."""

    list_display = [
        "id", "name", "state", "priority", "deadline", "material", "colour",
        "nozzle_diameter", "printer", "reason", "created_at",
    ]  # fmt: skip
    list_filter = ["state", "material"]
    search_fields = ["name", "sha256", "origin"]
    ordering = FarmJob._meta.ordering
    readonly_fields = [
        "name", "file", "size_bytes", "line_count", "sha256", "longest_command",
        "analysis", "state", "reason", "job", "printer", "origin", "uploaded_by",
        "created_at", "assigned_at", "cancelled_at",
    ]  # fmt: skip

    def has_add_permission(self, request: HttpRequest) -> bool:
        return False  # farm jobs come from uploads (their checks, their file)

    def get_readonly_fields(
        self, request: HttpRequest, obj: FarmJob | None = None
    ) -> list[str]:
        if obj is not None and obj.state != FarmJob.State.WAITING:
            return [field.name for field in FarmJob._meta.fields]
        return list(self.readonly_fields)
