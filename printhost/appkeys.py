"""OctoPrint's app-key pairing, which Cura uses to get an API key without typing one.

1. The app asks (`POST /plugin/appkeys/request`): a pending request with two tokens,
   one the app polls with, one a user decides with. Anyone may ask, so at most
   `PRINTHOST_APPKEY_PENDING_PER_ADDRESS` requests of one address (and `MAX_PENDING`
   in all) wait at once: beyond that, `TooManyRequests` (HTTP 429).
2. A logged-in user sees where the request came from and approves (choosing the
   printer the key is bound to and its role, never above their own) or denies it.
3. The app polls: 202 while pending, 200 with the key once (then the clear key is
   forgotten), 404 when denied or gone. A request expires
   `PRINTHOST_APPKEY_REQUEST_SECONDS` after it was made, or when the app stopped
   polling for `STALE_SECONDS`.
"""

from __future__ import annotations

import secrets
from datetime import datetime, timedelta
from typing import TYPE_CHECKING

from django.conf import settings
from django.db import transaction
from django.db.models import Q
from django.utils import timezone

from printhost.access import Forbidden, highest_role, issue_key, role_of
from printhost.models import AppKeyRequest, Role

if TYPE_CHECKING:
    from django.contrib.auth.models import AbstractBaseUser

    from printers.models import Printer

#: A pending request the app stopped polling for this long is dropped (OctoPrint: 5 s
#: poll interval, so a minute is generous).
STALE_SECONDS = 60.0

#: At most this many requests wait for a decision at once, from all addresses.
MAX_PENDING = 20

#: What a granted key may do when the approver does not say: an operator prints.
DEFAULT_ROLE = Role.OPERATOR


class TooManyRequests(Exception):
    """Too many pairing requests (of this address, or in all) wait already."""


def stale_before() -> datetime:
    return timezone.now() - timedelta(seconds=STALE_SECONDS)


def expired_before() -> datetime:
    return timezone.now() - timedelta(seconds=settings.PRINTHOST_APPKEY_REQUEST_SECONDS)


def _waiting() -> Q:
    """Pending, made within the expiry time, and polled recently."""
    return Q(
        state=AppKeyRequest.State.PENDING,
        created_at__gte=expired_before(),
        polled_at__gte=stale_before(),
    )


def expire() -> int:
    """Mark pending requests past their time as expired; how many were."""
    return (
        AppKeyRequest.objects.filter(state=AppKeyRequest.State.PENDING)
        .exclude(_waiting())
        .update(state=AppKeyRequest.State.EXPIRED)
    )


def pending() -> list[AppKeyRequest]:
    """Requests still waiting for a decision (expired and stale ones left out)."""
    return list(
        AppKeyRequest.objects.filter(_waiting())
        .select_related("printer")
        .order_by("created_at")
    )


def waiting(user_token: str) -> AppKeyRequest | None:
    """The request *user_token* names, if it still waits for a decision."""
    return (
        AppKeyRequest.objects.filter(_waiting(), user_token=user_token)
        .select_related("printer")
        .first()
    )


def open_request(
    app: str, user_hint: str = "", *, origin: str = "", printer: Printer | None = None
) -> AppKeyRequest:
    """A new pending request, unless its address (or everyone) asked too often."""
    expire()
    per_address = settings.PRINTHOST_APPKEY_PENDING_PER_ADDRESS
    waiting_now = AppKeyRequest.objects.filter(_waiting())
    if waiting_now.filter(origin=origin[:100]).count() >= per_address:
        raise TooManyRequests(
            f"{per_address} app key requests from {origin or 'this address'} already"
            " wait for a decision; decide or let them expire first"
        )
    if waiting_now.count() >= MAX_PENDING:
        raise TooManyRequests(
            f"{MAX_PENDING} app key requests already wait for a decision; try later"
        )
    return AppKeyRequest.objects.create(
        app=app[:100],
        user_hint=user_hint[:150],
        printer=printer,
        app_token=secrets.token_urlsafe(24),
        user_token=secrets.token_urlsafe(24),
        origin=origin[:100],
    )


def poll(app_token: str) -> tuple[str, str]:
    """(state, key): ("pending", ""), ("granted", key once) or ("gone", "")."""
    with transaction.atomic():
        row = (
            AppKeyRequest.objects.select_for_update()
            .filter(app_token=app_token)
            .first()
        )
        if row is None:
            return "gone", ""
        if row.state == AppKeyRequest.State.PENDING:
            if row.polled_at < stale_before() or row.created_at < expired_before():
                row.state = AppKeyRequest.State.EXPIRED
                row.save(update_fields=["state"])
                return "gone", ""
            row.polled_at = timezone.now()
            row.save(update_fields=["polled_at"])
            return "pending", ""
        if row.state == AppKeyRequest.State.GRANTED and row.handover:
            key, row.handover = row.handover, ""
            row.save(update_fields=["handover"])
            return "granted", key
        return "gone", ""


def grantable_role(
    user: AbstractBaseUser, printer: Printer | None, asked: int | None
) -> int:
    """The role a key of *user*'s for *printer* gets: *asked*, never above their own.

    Without *asked*: the operator role, or the user's own if lower. Raises Forbidden
    when the user holds no role there, or *asked* is above it.
    """
    held = role_of(user, printer) if printer is not None else highest_role(user)
    where = f"printer {printer.slug!r}" if printer is not None else "any printer"
    if held is None:
        raise Forbidden(f"you hold no role on {where}: you cannot grant a key for it")
    if asked is None:
        return min(DEFAULT_ROLE, held)
    if asked > held:
        raise Forbidden(
            f"you may grant at most your own role on {where}"
            f" ({Role(held).label.split()[0]}), not {Role(asked).label.split()[0]}"
        )
    return asked


def decide(
    row: AppKeyRequest,
    user: AbstractBaseUser,
    *,
    grant: bool,
    printer: Printer | None = None,
    role: int | None = None,
) -> AppKeyRequest:
    """A user approves (a new key of theirs, named for the app) or denies.

    The key is bound to *printer*, or to the printer the app asked through
    (`/p/<slug>/`); its role is `grantable_role` (Forbidden above the user's own).
    """
    with transaction.atomic():
        row = AppKeyRequest.objects.select_for_update().get(pk=row.pk)
        if row.state != AppKeyRequest.State.PENDING:
            return row
        if grant:
            bound = printer if printer is not None else row.printer
            capped = grantable_role(user, bound, role)
            key, raw = issue_key(
                user, f"{row.app} (app key)", printer=bound, role=capped
            )
            row.state, row.api_key, row.handover = AppKeyRequest.State.GRANTED, key, raw
        else:
            row.state = AppKeyRequest.State.DENIED
        row.save(update_fields=["state", "api_key", "handover"])
        return row
