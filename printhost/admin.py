"""Admin for accounts: roles, API keys (shown once), app-key requests and the audit log."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from django import forms
from django.contrib import admin, messages
from django.utils import timezone

from printhost.access import Forbidden, issue_key
from printhost.appkeys import decide
from printhost.logins import ThrottledAdminLoginForm
from printhost.models import ApiKey, AppKeyRequest, AuditEntry, PrinterRole, UserProfile

if TYPE_CHECKING:
    from django.db.models import QuerySet
    from django.http import HttpRequest

# The admin's login is throttled like every other password login.
admin.site.login_form = ThrottledAdminLoginForm


@admin.register(PrinterRole)
class PrinterRoleAdmin(admin.ModelAdmin):
    list_display = ["user", "printer", "role"]
    list_filter = ["role", "printer"]
    search_fields = ["user__username", "printer__slug"]


@admin.register(UserProfile)
class UserProfileAdmin(admin.ModelAdmin):
    list_display = ["user", "default_printer"]


class ApiKeyForm(forms.ModelForm):
    class Meta:
        model = ApiKey
        fields = ["user", "name", "printer", "role"]


@admin.register(ApiKey)
class ApiKeyAdmin(admin.ModelAdmin):
    list_display = [
        "name",
        "user",
        "prefix",
        "printer",
        "role",
        "created_at",
        "last_used_at",
        "revoked_at",
    ]
    list_filter = ["printer"]
    search_fields = ["name", "user__username", "prefix"]
    actions = ["revoke"]

    def get_form(self, request: HttpRequest, obj: Any = None, **kwargs: Any) -> Any:
        if obj is None:
            kwargs["form"] = ApiKeyForm
        return super().get_form(request, obj, **kwargs)

    def get_readonly_fields(self, request: HttpRequest, obj: Any = None) -> list[str]:
        if obj is None:
            return []
        return [
            "user",
            "prefix",
            "key_hash",
            "created_at",
            "last_used_at",
            "revoked_at",
        ]

    def save_model(
        self,
        request: HttpRequest,
        obj: ApiKey,
        form: Any,
        change: bool,  # noqa: FBT001
    ) -> None:
        if change:
            super().save_model(request, obj, form, change)
            return
        key, raw = issue_key(obj.user, obj.name, printer=obj.printer, role=obj.role)
        obj.pk, obj.prefix, obj.key_hash = key.pk, key.prefix, key.key_hash
        messages.warning(
            request,
            f"API key for {obj.user}: {raw}  (copy it now: it is not shown again)",
        )

    @admin.action(description="Revoke the selected keys", permissions=["change"])
    def revoke(self, request: HttpRequest, queryset: QuerySet[ApiKey]) -> None:
        count = queryset.filter(revoked_at__isnull=True).update(
            revoked_at=timezone.now()
        )
        messages.info(request, f"{count} key(s) revoked")


@admin.register(AppKeyRequest)
class AppKeyRequestAdmin(admin.ModelAdmin):
    list_display = [
        "app",
        "origin",
        "user_hint",
        "printer",
        "state",
        "created_at",
        "polled_at",
    ]
    list_filter = ["state"]
    exclude = ["handover", "app_token", "user_token"]
    readonly_fields = [
        "app",
        "user_hint",
        "state",
        "api_key",
        "created_at",
        "polled_at",
        "origin",
    ]
    actions = ["approve", "deny"]

    @admin.action(
        description="Approve: give the app an API key of mine (operator at most;"
        " the account page lets you choose the printer and role)",
        permissions=["change"],
    )
    def approve(self, request: HttpRequest, queryset: QuerySet[AppKeyRequest]) -> None:
        for row in queryset.filter(state=AppKeyRequest.State.PENDING):
            try:
                decide(row, request.user, grant=True)
            except Forbidden as error:
                messages.error(request, f"{row.app} from {row.origin}: {error}")
                return
        messages.info(request, "approved; the app picks its key up at its next poll")

    @admin.action(description="Deny", permissions=["change"])
    def deny(self, request: HttpRequest, queryset: QuerySet[AppKeyRequest]) -> None:
        for row in queryset.filter(state=AppKeyRequest.State.PENDING):
            decide(row, request.user, grant=False)


@admin.register(AuditEntry)
class AuditEntryAdmin(admin.ModelAdmin):
    list_display = ["time", "user", "client", "action", "printer", "job", "detail"]
    list_filter = ["action", "client", "printer"]
    search_fields = ["user__username", "detail", "origin"]

    def has_add_permission(self, request: HttpRequest) -> bool:
        return False

    def has_change_permission(self, request: HttpRequest, obj: Any = None) -> bool:
        return False
