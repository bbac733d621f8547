"""OctoPrint's app-key pairing over HTTP (Cura's "Request..." button).

probe (204), request (201 + Location to poll), poll (202 pending, 200 with the key
once, 404 denied or gone) are anonymous by the protocol's nature; a logged-in user
decides (`POST /plugin/appkeys/decision/<user_token>`, or the admin's approve action).
Every path is also served under `/p/<slug>/`, where Cura's base URL may point.
"""

from __future__ import annotations

from datetime import timedelta
from typing import Any

from django.conf import settings
from django.http import HttpRequest, HttpResponse, JsonResponse
from ninja import Router
from ninja.errors import HttpError

from printers.models import Printer
from printhost import appkeys
from printhost.access import Forbidden
from printhost.api.common import caller_of, envelope
from printhost.api.dialects import dialect_route, json_body
from printhost.audit import record
from printhost.models import AppKeyRequest, Role

router = Router(tags=["App keys (OctoPrint pairing)"])

#: Where the app sends its user to decide: the account page lists pending requests.
DECISION_PAGE = "/account/#apps-title"


@dialect_route(router, "GET", "/plugin/appkeys/probe", auth=None)
def appkeys_probe(request: HttpRequest, slug: str | None = None) -> HttpResponse:
    return HttpResponse(status=204)


@dialect_route(router, "POST", "/plugin/appkeys/request", auth=None)
def appkeys_request(request: HttpRequest, slug: str | None = None) -> JsonResponse:
    """`{"app": "Cura", "user": optional}` -> 201, Location to poll (absolute)."""
    body = json_body(request)
    app = body.get("app")
    if not isinstance(app, str) or not app.strip():
        raise HttpError(400, "give the app's name as 'app'")
    user_hint = body.get("user") or ""
    if not isinstance(user_hint, str):
        raise HttpError(400, "'user' must be a user name")
    printer = None
    if slug:
        printer = Printer.objects.filter(slug=slug).first()
        if printer is None:
            raise HttpError(404, f"Unknown printer {slug!r}")
    try:
        row = appkeys.open_request(
            app.strip(),
            user_hint.strip(),
            origin=request.META.get("REMOTE_ADDR", ""),
            printer=printer,
        )
    except appkeys.TooManyRequests as error:
        raise HttpError(429, str(error)) from None
    prefix = f"/p/{slug}" if slug else ""
    poll = request.build_absolute_uri(
        f"{prefix}/plugin/appkeys/request/{row.app_token}"
    )
    response = JsonResponse(
        {
            "app_token": row.app_token,
            "auth_dialog": request.build_absolute_uri(DECISION_PAGE),
        },
        status=201,
    )
    response["Location"] = poll
    return response


@dialect_route(router, "GET", "/plugin/appkeys/request/{app_token}", auth=None)
def appkeys_poll(
    request: HttpRequest, app_token: str, slug: str | None = None
) -> JsonResponse:
    """202 while pending, 200 with the key once, 404 when denied, stale or fetched."""
    state, key = appkeys.poll(app_token)
    if state == "pending":
        return JsonResponse({"message": "Awaiting decision"}, status=202)
    if state == "granted":
        return JsonResponse({"api_key": key})
    return JsonResponse({"error": "no such request (denied or expired)"}, status=404)


def _may_decide(request: HttpRequest, row: AppKeyRequest) -> None:
    caller = caller_of(request)
    if caller.key is not None:
        # A key is what a program holds: people decide, in their browser session.
        raise Forbidden("log in to decide on app key requests (an API key cannot)")
    named = bool(row.user_hint) and row.user_hint == caller.user.get_username()
    operator = bool(caller.printers(Role.OPERATOR))
    if not (named or operator):
        raise Forbidden("only an operator, or the user the app named, may decide")


ROLE_NAMES = {"viewer": Role.VIEWER, "operator": Role.OPERATOR, "admin": Role.ADMIN}


def _grant_choice(
    body: dict[str, Any], row: AppKeyRequest
) -> tuple[Printer | None, int | None]:
    """The printer the key is bound to and its role, from the decision's body."""
    printer = row.printer
    slug = body.get("printer")
    if slug not in (None, ""):
        if not isinstance(slug, str):
            raise HttpError(400, "'printer' must be a printer's slug or null")
        printer = Printer.objects.filter(slug=slug).first()
        if printer is None:
            raise HttpError(404, f"Unknown printer {slug!r}")
        if row.printer is not None and printer != row.printer:
            raise HttpError(
                400,
                f"the app asked through printer {row.printer.slug!r}: its key can"
                " only be bound to that printer",
            )
    name = body.get("role")
    if name in (None, ""):
        return printer, None
    if name not in ROLE_NAMES:
        raise HttpError(
            400, f"'role' must be one of {', '.join(ROLE_NAMES)}, not {name!r}"
        )
    return printer, ROLE_NAMES[name]


@router.post("/plugin/appkeys/decision/{user_token}")
def appkeys_decision(request: HttpRequest, user_token: str) -> HttpResponse:
    """`{"decision": true|false, "printer": slug, "role": "operator"}` from a user.

    Granting makes a key of the approver's, bound to `printer` (or to the printer
    the app asked through) with `role` (default: operator, or the approver's own
    role if lower; never above it: 403).
    """
    body = json_body(request)
    decision = body.get("decision")
    if not isinstance(decision, bool):
        raise HttpError(400, "give 'decision': true or false")
    row = appkeys.waiting(user_token)
    if row is None:
        raise HttpError(404, "no pending app key request with that token")
    _may_decide(request, row)
    printer, role = _grant_choice(body, row) if decision else (None, None)
    caller = caller_of(request)
    row = appkeys.decide(row, caller.user, grant=decision, printer=printer, role=role)
    action = "appkey.grant" if decision else "appkey.deny"
    record(caller, action, printer=printer, detail=f"{row.app} ({row.origin})")
    if decision and row.api_key is not None:
        key = row.api_key
        role_name = Role(key.role).label.split()[0] if key.role else "own roles"
        record(
            caller,
            "key.create",
            printer=key.printer,
            detail=f"{key.name} {key.prefix} ({role_name})",
        )
    return HttpResponse(status=204)


@router.get("/api/appkeys/pending")
def appkeys_pending(request: HttpRequest) -> JsonResponse:
    """Requests the caller may decide on (operators: all; others: those naming them).

    Each says where it came from (`origin`, the requesting address), the printer
    it asked through (if any) and when it expires.
    """
    caller = caller_of(request)
    rows = appkeys.pending()
    if not caller.printers(Role.OPERATOR):
        rows = [r for r in rows if r.user_hint == caller.user.get_username()]
    lifetime = timedelta(seconds=settings.PRINTHOST_APPKEY_REQUEST_SECONDS)
    return envelope(
        [
            {
                "app": r.app,
                "user": r.user_hint,
                "user_token": r.user_token,
                "origin": r.origin,
                "printer": r.printer.slug if r.printer_id else None,
                "created": r.created_at.isoformat(),
                "expires": (r.created_at + lifetime).isoformat(),
            }
            for r in rows
        ]
    )
