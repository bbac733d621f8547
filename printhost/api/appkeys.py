"""OctoPrint's app-key pairing over HTTP (Cura's "Request..." button).

probe (204), request (201 + Location to poll), poll (202 pending, 200 with the key
once, 404 denied or gone) are anonymous by the protocol's nature; a logged-in user
decides (`POST /plugin/appkeys/decision/<user_token>`, or the admin's approve action).
Every path is also served under `/p/<slug>/`, where Cura's base URL may point.
"""

from __future__ import annotations

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

#: Where the app sends its user to decide: the admin's list of pending requests.
DECISION_PAGE = "/admin/printhost/appkeyrequest/?state__exact=pending"


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
        row = appkeys.open_limited_request(
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
    if caller.key is not None and caller.key.printer_id is not None:
        raise Forbidden("a key bound to one printer cannot approve app keys")
    named = bool(row.user_hint) and row.user_hint == caller.user.get_username()
    operator = bool(caller.printers(Role.OPERATOR))
    if not (named or operator):
        raise Forbidden("only an operator, or the user the app named, may decide")


@router.post("/plugin/appkeys/decision/{user_token}")
def appkeys_decision(request: HttpRequest, user_token: str) -> HttpResponse:
    """`{"decision": true|false}` from a logged-in user: grant (a key of theirs) or deny."""
    decision = json_body(request).get("decision")
    if not isinstance(decision, bool):
        raise HttpError(400, "give 'decision': true or false")
    row = AppKeyRequest.objects.filter(
        user_token=user_token,
        state=AppKeyRequest.State.PENDING,
        polled_at__gte=appkeys.stale_before(),
    ).first()
    if row is None:
        raise HttpError(404, "no pending app key request with that token")
    _may_decide(request, row)
    caller = caller_of(request)
    row = appkeys.decide(row, caller.user, grant=decision)
    action = "appkey.grant" if decision else "appkey.deny"
    record(caller, action, detail=f"{row.app} ({row.origin})")
    if decision and row.api_key is not None:
        record(caller, "key.create", detail=f"{row.api_key.name} {row.api_key.prefix}")
    return HttpResponse(status=204)


@router.get("/api/appkeys/pending")
def appkeys_pending(request: HttpRequest) -> JsonResponse:
    """Requests the caller may decide on (operators: all; others: those naming them)."""
    caller = caller_of(request)
    rows = appkeys.pending()
    if not caller.printers(Role.OPERATOR):
        rows = [r for r in rows if r.user_hint == caller.user.get_username()]
    return envelope(
        [
            {
                "app": r.app,
                "user": r.user_hint,
                "user_token": r.user_token,
                "origin": r.origin,
                "created": r.created_at.isoformat(),
            }
            for r in rows
        ]
    )
