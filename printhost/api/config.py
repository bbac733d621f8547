"""The admin role's API: configure a printer, and give users roles.

An admin of a printer may change its settings, except its port and baud (a
superuser's: they decide what the server opens); an admin of every printer may also
give and take roles. (Superusers are admins everywhere; the Django admin does the
same through its forms.) `runhost` notices a changed printer within seconds and
restarts its worker with the new settings.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from django.contrib.auth import get_user_model
from django.core.exceptions import ValidationError as ModelValidationError
from django.http import HttpRequest, JsonResponse  # noqa: TC002 (ninja reads view hints)
from ninja import Router, Schema
from ninja.errors import HttpError

from printhost.api.common import caller_of, envelope, json_body, printer_for
from printhost.audit import record
from printhost.models import PrinterRole, Role

if TYPE_CHECKING:
    from printers.models import Printer

router = Router(tags=["Configuration (admin role)"])

#: Printer settings an admin may read and change through the API.
SETTINGS = (
    "name", "enabled", "port", "baud", "firmware", "checksums", "flow", "rx_buffer",
    "bufsize", "max_line_length", "ack_timeout", "busy_timeout", "max_resends",
    "temperature_interval", "status_interval", "connect_script", "start_script",
    "end_script", "pause_script", "resume_script", "abort_script",
    "quickstop_on_abort", "auto_start",
    "response_log_limit", "job_file_days",
)  # fmt: skip
#: Settings only a superuser may change: they name what the server opens.
SUPERUSER_SETTINGS = ("port", "baud")
ROLE_NAMES = {"viewer": Role.VIEWER, "operator": Role.OPERATOR, "admin": Role.ADMIN}


def _settings_of(printer: Printer) -> dict[str, Any]:
    return {"slug": printer.slug} | {name: getattr(printer, name) for name in SETTINGS}


@router.get("/printer/config/{slug}")
def get_config(request: HttpRequest, slug: str) -> JsonResponse:
    """The printer's settings."""
    printer = printer_for(request, slug, Role.ADMIN)
    return envelope(_settings_of(printer))


@router.patch("/printer/config/{slug}")
def change_config(request: HttpRequest, slug: str) -> JsonResponse:
    """Change some settings: `{"baud": 250000, "auto_start": true}`.

    Unknown names and invalid values are refused (400) and nothing is saved.
    """
    printer = printer_for(request, slug, Role.ADMIN)
    changes = json_body(request)
    if not changes:
        raise HttpError(400, "send a JSON object of settings to change")
    unknown = sorted(set(changes) - set(SETTINGS))
    if unknown:
        raise HttpError(400, f"not a printer setting: {', '.join(unknown)}")
    caller = caller_of(request)
    guarded = sorted(
        name
        for name in SUPERUSER_SETTINGS
        if name in changes and changes[name] != getattr(printer, name)
    )
    if guarded and not getattr(caller.user, "is_superuser", False):
        raise HttpError(
            403,
            f"changing a printer's {' and '.join(guarded)} needs a superuser "
            "(it decides what the server opens)",
        )
    for name, value in changes.items():
        setattr(printer, name, value)
    try:
        # Only what changes is checked: a setting stored before a check existed
        # does not block changing another one (the worker refuses a bad port).
        unchanged = [f.name for f in printer._meta.fields if f.name not in changes]
        printer.full_clean(exclude=unchanged, validate_unique=True)
    except (ModelValidationError, TypeError, ValueError) as error:
        messages = getattr(error, "message_dict", None) or {"": [str(error)]}
        text = "; ".join(
            f"{k}: {' '.join(v)}" if k else " ".join(v) for k, v in messages.items()
        )
        raise HttpError(400, f"invalid settings: {text}") from None
    printer.save(update_fields=list(changes))
    record(caller, "printer.configure", printer=printer, detail=str(changes))
    return envelope(_settings_of(printer))


class RoleChange(Schema):
    printer: str | None = None
    role: str | None = None


@router.get("/api/users")
def list_users(request: HttpRequest) -> JsonResponse:
    """Every user and their roles (admin of every printer)."""
    caller_of(request).require(None, Role.ADMIN)
    users = (
        get_user_model()
        .objects.order_by("username")
        .prefetch_related("printer_roles__printer")
    )
    return envelope(
        [
            {
                "username": user.username,
                "active": user.is_active,
                "superuser": user.is_superuser,
                "roles": [
                    {
                        "printer": r.printer.slug if r.printer_id else None,
                        "role": Role(r.role).name.lower(),
                    }
                    for r in user.printer_roles.all()
                ],
            }
            for user in users
        ]
    )


@router.post("/api/users/{username}/role")
def set_role(request: HttpRequest, username: str, change: RoleChange) -> JsonResponse:
    """Give *username* a role on a printer (or on every printer), or take it (`null`).

    An admin of a printer may set roles on it; roles on every printer need an admin
    of every printer.
    """
    caller = caller_of(request)
    printer = None
    if change.printer:
        printer = printer_for(request, change.printer, Role.ADMIN)
    else:
        caller.require(None, Role.ADMIN)
    if change.role is not None and change.role not in ROLE_NAMES:
        raise HttpError(400, f"role must be one of {', '.join(ROLE_NAMES)} or null")
    user = get_user_model().objects.filter(username=username).first()
    if user is None:
        raise HttpError(404, f"unknown user {username!r}")
    PrinterRole.objects.filter(user=user, printer=printer).delete()
    if change.role is not None:
        PrinterRole.objects.create(
            user=user, printer=printer, role=ROLE_NAMES[change.role]
        )
    where = printer.slug if printer else "every printer"
    record(
        caller,
        "role.set",
        printer=printer,
        detail=f"{username}: {change.role} on {where}",
    )
    return envelope(
        {"username": username, "printer": change.printer, "role": change.role}
    )
