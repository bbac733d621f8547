"""OctoPrint's app-key pairing, which Cura uses to get an API key without typing one.

1. The app asks (`POST /plugin/appkeys/request`): a pending request with two tokens,
   one the app polls with, one a user decides with.
2. A logged-in user approves or denies it (UI or admin).
3. The app polls: 202 while pending, 200 with the key once (then the clear key is
   forgotten), 404 when denied or stale (not polled for `STALE_SECONDS`).
"""

from __future__ import annotations

import secrets
from datetime import timedelta
from typing import TYPE_CHECKING

from django.db import transaction
from django.utils import timezone

from printhost.access import issue_key
from printhost.models import AppKeyRequest

if TYPE_CHECKING:
    from django.contrib.auth.models import AbstractBaseUser

    from printers.models import Printer

#: A pending request the app stopped polling for this long is dropped (OctoPrint: 5 s
#: poll interval, so a minute is generous).
STALE_SECONDS = 60.0


def open_request(
    app: str, user_hint: str = "", *, origin: str = "", printer: Printer | None = None
) -> AppKeyRequest:
    return AppKeyRequest.objects.create(
        app=app[:100],
        user_hint=user_hint[:150],
        printer=printer,
        app_token=secrets.token_urlsafe(24),
        user_token=secrets.token_urlsafe(24),
        origin=origin[:100],
    )


def stale_before() -> timezone.datetime:
    return timezone.now() - timedelta(seconds=STALE_SECONDS)


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
            if row.polled_at < stale_before():
                row.state = AppKeyRequest.State.DENIED
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


def decide(row: AppKeyRequest, user: AbstractBaseUser, *, grant: bool) -> AppKeyRequest:
    """A user approves (a new key of theirs, named for the app) or denies."""
    with transaction.atomic():
        row = AppKeyRequest.objects.select_for_update().get(pk=row.pk)
        if row.state != AppKeyRequest.State.PENDING:
            return row
        if grant:
            # Asked through /p/<slug>/: the key works for that printer only.
            key, raw = issue_key(user, f"{row.app} (app key)", printer=row.printer)
            row.state, row.api_key, row.handover = AppKeyRequest.State.GRANTED, key, raw
        else:
            row.state = AppKeyRequest.State.DENIED
        row.save(update_fields=["state", "api_key", "handover"])
        return row


#: At most this many requests wait for a decision at once (anyone may ask, so the
#: table must not grow without bound).
MAX_PENDING = 20


class TooManyRequests(Exception):
    """Too many pairing requests wait for a decision already."""


def pending() -> list[AppKeyRequest]:
    """Requests still waiting for a decision (stale ones are left out)."""
    return list(
        AppKeyRequest.objects.filter(
            state=AppKeyRequest.State.PENDING, polled_at__gte=stale_before()
        ).order_by("created_at")
    )


def open_limited_request(
    app: str, user_hint: str = "", *, origin: str = "", printer: Printer | None = None
) -> AppKeyRequest:
    """`open_request`, refused once `MAX_PENDING` requests wait; stale ones expire."""
    AppKeyRequest.objects.filter(
        state=AppKeyRequest.State.PENDING, polled_at__lt=stale_before()
    ).update(state=AppKeyRequest.State.DENIED)
    if len(pending()) >= MAX_PENDING:
        raise TooManyRequests(
            f"{MAX_PENDING} app key requests already wait for a decision; try later"
        )
    return open_request(app, user_hint, origin=origin, printer=printer)
