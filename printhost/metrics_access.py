"""Who may read /metrics: the scrape token, or else an admin of every printer.

With PRINTHOST_METRICS_TOKEN set, only `Authorization: Bearer <token>` is let in
(compared in constant time); sessions and API keys are not, so the token is the one
secret a Prometheus server holds. Without it, the caller must hold the admin role on
every printer (a superuser, or an all-printers admin role), through a session or an
API key (a Bearer key works, which is what a scrape config can send); a key bound to
one printer is refused, as the figures cover them all.

Refusals: 401 (no or wrong credentials) or 403 (known caller, not an admin). The
request's body is never read.
"""

from __future__ import annotations

import hmac
import ipaddress
from dataclasses import dataclass
from typing import TYPE_CHECKING

from django.conf import settings
from django.db import connection

from printers.host_role import reads_keys
from printhost.access import (
    Caller,
    NotAuthenticated,
    caller_from_key,
    caller_from_request,
)
from printhost.models import Role

if TYPE_CHECKING:
    from django.http import HttpRequest


@dataclass(frozen=True)
class Refusal:
    """Why a scrape is refused: an HTTP status and a message for the operator."""

    status: int
    message: str


NO_TOKEN = Refusal(
    401, "send the scrape token as `Authorization: Bearer <PRINTHOST_METRICS_TOKEN>`"
)
WRONG_TOKEN = Refusal(401, "wrong scrape token (PRINTHOST_METRICS_TOKEN)")
NO_CREDENTIALS = Refusal(
    401, "log in as an admin, or send an admin's API key as `Authorization: Bearer`"
)


def bearer(authorization: str) -> str:
    """The credential of an `Authorization: Bearer <credential>` header, or ""."""
    scheme, _, value = authorization.strip().partition(" ")
    return value.strip() if scheme.lower() == "bearer" else ""


def token_refusal(authorization: str, token: str) -> Refusal | None:
    """None if *authorization* carries *token*."""
    given = bearer(authorization)
    if not given:
        return NO_TOKEN
    if not hmac.compare_digest(given.encode(), token.encode()):
        return WRONG_TOKEN
    return None


def caller_refusal(caller: Caller | None) -> Refusal | None:
    """None if *caller* is an admin of every printer, through an unbound key or a session."""
    if caller is None or not caller.authenticated:
        return NO_CREDENTIALS
    if caller.bound_printer_id is not None:
        return Refusal(
            403, "this API key is bound to one printer; metrics cover every printer"
        )
    if not caller.can(None, Role.ADMIN):
        return Refusal(403, "metrics need the admin role on every printer")
    return None


def request_refusal(request: HttpRequest) -> Refusal | None:
    """Why the control plane's /metrics refuses *request*, or None."""
    token = settings.PRINTHOST_METRICS_TOKEN
    if token:
        return token_refusal(request.headers.get("Authorization", ""), token)
    try:
        caller = caller_from_request(request, client="metrics")
    except NotAuthenticated:
        return Refusal(401, "invalid or revoked API key")
    return caller_refusal(caller)


def header_refusal(authorization: str, address: str = "") -> Refusal | None:
    """Why a worker host's `serve_metrics` refuses a scrape (no sessions there)."""
    token = settings.PRINTHOST_METRICS_TOKEN
    if token:
        return token_refusal(authorization, token)
    key = bearer(authorization)
    if not key:
        return NO_CREDENTIALS
    caller = caller_from_key(key, client="metrics", address=address)
    if caller is None:
        return Refusal(401, "invalid or revoked API key")
    return caller_refusal(caller)


def key_check_refusal() -> str:
    """Why a worker host's metrics server could not check a scrape's API key ("" if
    it can): a worker host on its own database role (printers/host_role.py) may not
    read the farm's keys, so its scrapes need PRINTHOST_METRICS_TOKEN."""
    if settings.PRINTHOST_METRICS_TOKEN or reads_keys(connection):
        return ""
    return (
        "this database role may not read the farm's API keys (a worker host's own "
        "role): set PRINTHOST_METRICS_TOKEN, which scrapes then show instead"
    )


def bind_refusal(bind: str) -> str:
    """Why a worker host's metrics server may not listen on *bind* ("" if it may).

    Beyond this computer only with PRINTHOST_METRICS_TOKEN: without it a scrape
    needs an admin's API key, which Prometheus would send in clear (the server
    speaks plain HTTP) to every worker host, and a key that runs the farm.
    """
    if settings.PRINTHOST_METRICS_TOKEN:
        return ""
    try:
        local = ipaddress.ip_address(bind.strip("[]")).is_loopback
    except ValueError:
        local = bind == "localhost"
    if local:
        return ""
    return (
        f"metrics on {bind} would answer other computers: set "
        "PRINTHOST_METRICS_TOKEN first (without it a scrape must send an admin's "
        "API key, in clear), or bind to 127.0.0.1"
    )
