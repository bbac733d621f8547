"""Who a websocket handshake comes from: its API key or session, and its parameters.

Used by the live-feed consumers (printers/consumers.py) on connect and on every
periodic re-check: a revoked key or an ended session closes the connection.
"""

from __future__ import annotations

from collections import Counter
from importlib import import_module
from typing import Any
from urllib.parse import parse_qs

from django.conf import settings
from django.contrib.auth import get_user
from django.contrib.auth.models import AbstractBaseUser, AnonymousUser
from django.http import HttpRequest

from printhost.access import Caller, caller_from_key

__all__ = [
    "CLOSE_FORBIDDEN",
    "CLOSE_NOT_FOUND",
    "CLOSE_TOO_MANY",
    "CLOSE_UNAUTHENTICATED",
    "Refused",
    "caller_from_scope",
    "hold_place",
    "int_param",
    "key_from_scope",
    "leave_place",
    "query_of",
    "session_user",
]

#: Close codes: the HTTP status plus 4000, as many websocket APIs do.
CLOSE_UNAUTHENTICATED = 4401
CLOSE_FORBIDDEN = 4403
CLOSE_NOT_FOUND = 4404
CLOSE_TOO_MANY = 4429

#: Feeds open in this process, per user (`hold_place`): the event loop's only.
_open: Counter[int] = Counter()


class Refused(Exception):
    """The connection may not go on: close with *code* after saying why."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


def key_from_scope(scope: dict[str, Any]) -> str | None:
    """The API key a websocket handshake carries, if any."""
    headers = {name.lower(): value for name, value in scope.get("headers", [])}
    if headers.get(b"x-api-key"):
        return headers[b"x-api-key"].decode("latin1").strip()
    scheme, _, value = (
        headers.get(b"authorization", b"").decode("latin1").partition(" ")
    )
    if scheme.lower() == "bearer" and value.strip():
        return value.strip()
    query = query_of(scope)
    for name in ("apikey", "token"):
        if query.get(name):
            return query[name].strip()
    return None


def query_of(scope: dict[str, Any]) -> dict[str, str]:
    raw = scope.get("query_string", b"").decode("latin1")
    return {name: values[-1] for name, values in parse_qs(raw).items()}


def caller_from_scope(scope: dict[str, Any]) -> Caller:
    """The caller of a handshake (sync: reads keys). Raises Refused(4401)."""
    client = scope.get("client") or ("", 0)
    address = str(client[0] or "")
    raw = key_from_scope(scope)
    if raw is not None:
        caller = caller_from_key(raw, client="websocket", address=address)
        if caller is None:
            raise Refused(CLOSE_UNAUTHENTICATED, "invalid or revoked API key")
        return caller
    user = session_user(scope)
    if not user.is_authenticated:
        if (scope.get("user") or AnonymousUser()).is_authenticated:
            message = "your session ended (logged out, expired or deactivated)"
            raise Refused(CLOSE_UNAUTHENTICATED, message)
        raise Refused(CLOSE_UNAUTHENTICATED, "log in or give an API key")
    return Caller(client="websocket", user=user, address=address)


def session_user(scope: dict[str, Any]) -> AbstractBaseUser | AnonymousUser:
    """The user the handshake's session names now, read afresh from the session store.

    The scope's session and user were loaded once, at the handshake; a logout, a
    flushed or expired session, a changed password or `is_active=False` since then
    gives an anonymous user here (Django's own `get_user` rules), so the periodic
    re-check closes the connection.
    """
    session_key = getattr(scope.get("session"), "session_key", None)
    if not session_key:
        return AnonymousUser()
    request = HttpRequest()
    request.session = import_module(settings.SESSION_ENGINE).SessionStore(
        session_key=session_key
    )
    return get_user(request)


def int_param(query: dict[str, str], name: str) -> int | None:
    value = query.get(name)
    if value is None or value == "":
        return None
    try:
        number = int(value)
    except ValueError:
        raise Refused(4400, f"{name} must be a whole number, not {value!r}") from None
    if number < 0:
        raise Refused(4400, f"{name} must not be negative")
    return number


def hold_place(caller: Caller) -> int:
    """Count a feed of *caller*'s user in this process; Refused (4429) past
    `PRINTHOST_WS_MAX_PER_USER`, which keeps one key or login from holding the
    server's connections, memory and database reads. Returns what to hand back to
    `leave_place`. Called on the event loop (the count is not locked)."""
    user = caller.user.pk
    most = settings.PRINTHOST_WS_MAX_PER_USER
    if _open[user] >= most:
        raise Refused(
            CLOSE_TOO_MANY,
            f"too many live feeds for this user on this server (at most {most}); "
            "close some, or try again later",
        )
    _open[user] += 1
    return user


def leave_place(user: int) -> None:
    _open[user] -= 1
    if _open[user] <= 0:
        del _open[user]
