"""A user's API keys: list, create (the key is shown once), revoke.

Only a SHA-256 of a key is stored. A key bound to one printer can only create keys
bound to the same printer, so a key never mints a wider one.
"""

from __future__ import annotations

from typing import Any

from django.http import HttpRequest, HttpResponse, JsonResponse
from django.utils import timezone
from ninja import Router, Schema
from ninja.errors import HttpError

from printers.models import Printer
from printhost.access import Forbidden, issue_key, role_of
from printhost.api.common import caller_of, envelope
from printhost.audit import record
from printhost.models import ApiKey, Role

router = Router(tags=["API keys"])


class NewKey(Schema):
    name: str
    printer: str | None = None


def _key_info(key: ApiKey) -> dict[str, Any]:
    def when(value: Any) -> str | None:
        return value.isoformat() if value else None

    return {
        "id": key.pk,
        "name": key.name,
        "prefix": key.prefix,
        "printer": key.printer.slug if key.printer_id else None,
        # The most the key may do (None: whatever its user may).
        "role": Role(key.role).name.lower() if key.role else None,
        "created": when(key.created_at),
        "last_used": when(key.last_used_at),
        "revoked": when(key.revoked_at),
    }


@router.get("/api/keys")
def list_keys(request: HttpRequest) -> JsonResponse:
    """The caller's own keys (never the keys themselves: only their prefixes)."""
    caller = caller_of(request)
    keys = ApiKey.objects.filter(user=caller.user).select_related("printer")
    return envelope([_key_info(k) for k in keys])


@router.post("/api/keys")
def create_key(request: HttpRequest, body: NewKey) -> JsonResponse:
    """A new key of the caller's, optionally bound to one printer; 201, shown once."""
    caller = caller_of(request)
    name = body.name.strip()
    if not name:
        raise HttpError(400, "give the key a name (what it is for)")
    printer = None
    if body.printer:
        printer = Printer.objects.filter(slug=body.printer).first()
        if printer is None:
            raise HttpError(404, f"Unknown printer {body.printer!r}")
        caller.require(printer, Role.VIEWER)
    bound = caller.bound_printer_id
    if bound is not None and (printer is None or printer.pk != bound):
        raise Forbidden(
            "this API key is bound to one printer: it can only create keys bound to it"
        )
    key, raw = issue_key(caller.user, name, printer=printer)
    record(caller, "key.create", printer=printer, detail=f"{key.name} {key.prefix}")
    data = _key_info(key)
    data["key"] = raw
    return envelope(data, status=201)


@router.delete("/api/keys/{key_id}")
def revoke_key(request: HttpRequest, key_id: int) -> HttpResponse:
    """Revoke one of your keys (an admin of every printer may revoke anyone's)."""
    caller = caller_of(request)
    key = ApiKey.objects.filter(pk=key_id).select_related("printer").first()
    admin = caller.bound_printer_id is None and role_of(caller.user, None) == Role.ADMIN
    if key is None or (key.user_id != caller.user.pk and not admin):
        raise HttpError(404, f"no API key {key_id} of yours")
    if key.revoked_at is None:
        ApiKey.objects.filter(pk=key.pk).update(revoked_at=timezone.now())
        record(
            caller,
            "key.revoke",
            printer=key.printer,
            detail=f"{key.name} {key.prefix} of {key.user}",
        )
    return HttpResponse(status=204)
