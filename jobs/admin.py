"""Jobs in the Django admin: list, filter, search and act on them."""

from __future__ import annotations

from typing import TYPE_CHECKING

from django.contrib import admin, messages

from jobs.models import ACTIVE_STATES, Job
from jobs.services import delete_job_file, request_action
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
        "state",
        "message",
    ]
    actions = ["abort", "requeue", "mark_bed_clear", "delete_with_files"]

    @admin.display(description="progress")
    def progress_percent(self, job: Job) -> str:
        return f"{job.progress * 100:.1f} %"

    @admin.action(description="Abort the running job")
    def abort(self, request: HttpRequest, queryset: QuerySet[Job]) -> None:
        caller = admin_caller(request)
        for job in queryset.filter(state__in=ACTIVE_STATES):
            request_action(job.printer, "abort", origin=caller.origin)
            record(caller, "abort", printer=job.printer, job=job)

    @admin.action(description="Queue again")
    def requeue(self, request: HttpRequest, queryset: QuerySet[Job]) -> None:
        caller = admin_caller(request)
        for job in queryset.exclude(state__in=ACTIVE_STATES):
            record(caller, "requeue", printer=job.printer, job=job)
        count = queryset.exclude(state__in=ACTIVE_STATES).update(
            state=Job.State.QUEUED,
            lines_sent=0,
            lines_acked=0,
            bytes_acked=0,
            message="",
            started_at=None,
            finished_at=None,
        )
        messages.info(request, f"{count} job(s) queued again")

    @admin.action(description="The bed is clear: their printers start the next job")
    def mark_bed_clear(self, request: HttpRequest, queryset: QuerySet[Job]) -> None:
        caller = admin_caller(request)
        printers = {job.printer for job in queryset.select_related("printer")}
        waiting = [p for p in printers if p.state == Printer.State.WAITSTART]
        for printer in waiting:
            request_action(printer, "bed_clear", origin=caller.origin)
            record(caller, "bed_clear", printer=printer)
        messages.info(request, f"asked {len(waiting)} waiting printer(s) to start")

    @admin.action(description="Delete with their files")
    def delete_with_files(self, request: HttpRequest, queryset: QuerySet[Job]) -> None:
        busy = queryset.filter(state__in=ACTIVE_STATES).count()
        caller = admin_caller(request)
        for job in queryset.exclude(state__in=ACTIVE_STATES):
            record(caller, "delete", printer=job.printer, detail=job.name)
            delete_job_file(job)
            job.delete()
        if busy:
            messages.warning(request, f"{busy} running job(s) kept: abort them first")
