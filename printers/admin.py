"""Printers, the request queue and the response log in the Django admin."""

from __future__ import annotations

from typing import TYPE_CHECKING

from django.contrib import admin, messages

from jobs.commands import emergency_stop, request_action
from printers.heartbeat import HostRefused, release
from printers.hosts import WorkerHost
from printers.models import Printer, QueuedCommand, ResponseLine

if TYPE_CHECKING:
    from django.db.models import QuerySet
    from django.http import HttpRequest
from printhost.access import admin_caller
from printhost.audit import record

#: Printer fields only a superuser may change (what the server opens and runs).
SUPERUSER_FIELDS = ("port", "baud", "simulator", "worker_host")


@admin.register(Printer)
class PrinterAdmin(admin.ModelAdmin):
    list_display = [
        "name",
        "slug",
        "firmware",
        "worker_host",
        "port",
        "material",
        "state",
        "enabled",
    ]
    list_filter = ["firmware", "state", "enabled", "worker_host", "material"]
    search_fields = ["name", "slug", "port"]
    prepopulated_fields = {"slug": ["name"]}
    readonly_fields = [
        "state",
        "state_message",
        "firmware_name",
        "capabilities",
        "temperatures",
        "machine_status",
        "lease_owner",
        "lease_expires_at",
        "worker_seen_at",
        "link_stats",
    ]
    actions = ["mark_bed_clear", "stop_now", "reconnect"]
    fieldsets = [
        (
            None,
            {
                "fields": [
                    "name",
                    "slug",
                    "enabled",
                    "worker_host",
                    "port",
                    "baud",
                    "firmware",
                ]
            },
        ),
        (
            "Link",
            {
                "fields": [
                    "checksums",
                    "flow",
                    "rx_buffer",
                    "bufsize",
                    "max_line_length",
                    "ack_timeout",
                    "busy_timeout",
                    "max_resends",
                    "temperature_interval",
                    "status_interval",
                ]
            },
        ),
        (
            "Scripts",
            {
                "fields": [
                    "connect_script",
                    "start_script",
                    "end_script",
                    "pause_script",
                    "resume_script",
                    "abort_script",
                    "quickstop_on_abort",
                    "auto_start",
                ]
            },
        ),
        (
            "File analysis (time estimates and filament)",
            {"fields": ["motion_profile", "filament_diameter", "filament_density"]},
        ),
        (
            "Farm (what a farm job may ask for)",
            {
                "fields": [
                    "farm",
                    "profile",
                    "tags",
                    "build_volume",
                    "material",
                    "colour",
                    "nozzle_diameter",
                    "loaded_by",
                    "loaded_at",
                ]
            },
        ),
        (
            "Other",
            {
                "fields": [
                    "response_log_limit",
                    "job_file_days",
                    "terminal_port",
                    "simulator",
                ]
            },
        ),
        ("Live (written by the worker)", {"fields": readonly_fields}),
    ]

    def get_readonly_fields(
        self, request: HttpRequest, obj: Printer | None = None
    ) -> list[str]:
        """Port, baud and simulator decide what the server opens: superusers only."""
        fields = list(super().get_readonly_fields(request, obj))
        if not request.user.is_superuser:
            fields += [name for name in SUPERUSER_FIELDS if name not in fields]
        return fields

    @admin.action(
        description="The bed is clear: start the next job", permissions=["change"]
    )
    def mark_bed_clear(self, request: HttpRequest, queryset: QuerySet[Printer]) -> None:
        caller = admin_caller(request)
        for printer in queryset:
            request_action(printer, "bed_clear", origin=caller.origin)
            record(caller, "bed_clear", printer=printer)
        messages.info(request, f"asked {queryset.count()} printer(s) to start")

    @admin.action(description="EMERGENCY STOP", permissions=["change"])
    def stop_now(self, request: HttpRequest, queryset: QuerySet[Printer]) -> None:
        caller = admin_caller(request)
        for printer in queryset:
            emergency_stop(printer, origin=caller.origin)
            record(caller, "emergency_stop", printer=printer)
        messages.warning(
            request, f"emergency stop sent to {queryset.count()} printer(s)"
        )

    @admin.action(description="Reconnect", permissions=["change"])
    def reconnect(self, request: HttpRequest, queryset: QuerySet[Printer]) -> None:
        caller = admin_caller(request)
        for printer in queryset:
            request_action(printer, "reconnect", origin=caller.origin)
            record(caller, "reconnect", printer=printer)


@admin.register(QueuedCommand)
class QueuedCommandAdmin(admin.ModelAdmin):
    list_display = [
        "id",
        "printer",
        "kind",
        "text",
        "state",
        "reply",
        "origin",
        "created_at",
    ]
    list_filter = ["kind", "state", "printer"]
    search_fields = ["text", "origin"]
    readonly_fields = ["state", "reply", "done_at"]


@admin.register(ResponseLine)
class ResponseLineAdmin(admin.ModelAdmin):
    list_display = ["seq", "printer", "time", "kind", "text"]
    list_filter = ["printer", "kind"]
    search_fields = ["text"]

    def has_add_permission(self, request: HttpRequest) -> bool:
        return False

    def has_change_permission(self, request: HttpRequest, obj: object = None) -> bool:
        return False


@admin.register(WorkerHost)
class WorkerHostAdmin(admin.ModelAdmin):
    """Hosts are added here or with `manage.py worker_host add NAME` (which shows
    the key); the heartbeat fields are the host's runhost's to write."""

    list_display = ["name", "hostname", "version", "seen_at", "enabled", "online"]
    search_fields = ["name", "hostname", "description"]
    readonly_fields = [
        "key_prefix",
        "instance",
        "hostname",
        "version",
        "started_at",
        "seen_at",
        "load",
        "printers",
        "metrics_address",
    ]

    actions = ["release_hosts"]

    @admin.display(boolean=True)
    def online(self, host: WorkerHost) -> bool:
        return host.online

    @admin.action(
        description="Release: their computers are gone for good",
        permissions=["change"],
    )
    def release_hosts(
        self, request: HttpRequest, queryset: QuerySet[WorkerHost]
    ) -> None:
        caller = admin_caller(request)
        if not request.user.is_superuser:
            # Like moving a printer to another host (SUPERUSER_FIELDS).
            messages.error(request, "only a superuser may release a worker host")
            return
        for host in queryset:
            try:
                release(host)
            except HostRefused as error:
                messages.error(request, str(error))
                continue
            record(caller, "worker_host.release", detail=host.name)
            messages.info(request, f"released worker host {host.name}")
