"""Who is asking, and may they: API keys, sessions, roles and the caller's context.

Every connection is a client with a context (ESP3D's module clients): its type
(http, websocket, telnet), the user and the role that user holds on the printer, its
origin (address, key) and, for a key bound to one printer, that printer. Views,
consumers and the terminal build a `Caller` once and ask it `require(printer, role)`.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from django.contrib.auth.models import AnonymousUser
from django.core.exceptions import PermissionDenied
from django.utils import timezone

from printers.models import Printer
from printhost.models import ApiKey, PrinterRole, Role

if TYPE_CHECKING:
    from collections.abc import Collection

    from django.contrib.auth.models import AbstractBaseUser
    from django.http import HttpRequest

#: Keys look like `ph_<10 prefix chars><32 secret chars>`, letters and digits only,
#: so every slicer's settings field and every header takes them unchanged.
KEY_START = "ph_"
_PREFIX_LEN = 10
_ALPHABET = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789"


class NotAuthenticated(Exception):
    """No credentials, or credentials that match nobody (HTTP 401)."""


class Forbidden(PermissionDenied):
    """Known caller, not allowed (HTTP 403)."""


def _random(n: int) -> str:
    return "".join(secrets.choice(_ALPHABET) for _ in range(n))


def hash_key(raw: str) -> str:
    return hashlib.sha256(raw.encode()).hexdigest()


def issue_key(
    user: AbstractBaseUser,
    name: str,
    *,
    printer: Printer | None = None,
    role: int | None = None,
) -> tuple[ApiKey, str]:
    """Create a key for *user* (bound to *printer*, capped at *role* if given).

    Returns the row and the key in clear (shown once).
    """
    prefix = _random(_PREFIX_LEN)
    raw = f"{KEY_START}{prefix}{_random(32)}"
    key = ApiKey.objects.create(
        user=user,
        name=name[:100] or "API key",
        prefix=prefix,
        key_hash=hash_key(raw),
        printer=printer,
        role=role,
    )
    return key, raw


def find_key(raw: str) -> ApiKey | None:
    """The active key *raw* names, or None (unknown, revoked, malformed)."""
    raw = raw.strip()
    if not raw.startswith(KEY_START) or len(raw) < len(KEY_START) + _PREFIX_LEN + 1:
        return None
    prefix = raw[len(KEY_START) : len(KEY_START) + _PREFIX_LEN]
    # Every API call starts here: one row by its unique prefix, with its user and
    # no ordering (`get`, not `first`). The key's printer is read only where it is
    # named (a bound key's uploads and refusals), not joined into every call.
    try:
        key = ApiKey.objects.select_related("user").get(
            prefix=prefix, revoked_at__isnull=True
        )
    except ApiKey.DoesNotExist:
        return None
    if not hmac.compare_digest(key.key_hash, hash_key(raw)):
        return None
    if not key.user.is_active:
        return None
    now = timezone.now()
    if key.last_used_at is None or (now - key.last_used_at).total_seconds() > 60:
        ApiKey.objects.filter(pk=key.pk).update(last_used_at=now)
    return key


def key_from_request(request: HttpRequest) -> str | None:
    """The key a request carries: X-Api-Key, `Authorization: Bearer`, ?apikey= or ?token=."""
    header = request.headers.get("X-Api-Key")
    if header:
        return header.strip()
    authorization = request.headers.get("Authorization", "")
    scheme, _, value = authorization.partition(" ")
    if scheme.lower() == "bearer" and value.strip():
        return value.strip()
    for name in ("apikey", "token"):
        value = request.GET.get(name)
        if value:
            return value.strip()
    return None


@dataclass(frozen=True, slots=True)
class Grants:
    """The roles one user holds, read once: on every printer, and on single ones.

    A list of printers asks each one's role from the same read (one query, not one
    a printer). Read afresh for each question that must see changes (a live
    connection's periodic re-check), never kept on a long-lived `Caller`.
    """

    everywhere: int | None = None
    on_printer: dict[int, int] = field(default_factory=dict)
    superuser: bool = False
    staff: bool = False

    def on(self, printer: Printer | None) -> int | None:
        """The highest role on *printer* (None = on every printer)."""
        if self.superuser:
            return Role.ADMIN
        held = [self.everywhere]
        if printer is not None:
            held.append(self.on_printer.get(printer.pk))
        best = max((r for r in held if r is not None), default=None)
        if best is None and self.staff:
            return Role.VIEWER
        return best


def grants_of(user: AbstractBaseUser | AnonymousUser) -> Grants | None:
    """What *user* holds (None: not logged in or inactive); a superuser costs no
    query, anyone else one."""
    if not user.is_authenticated or not user.is_active:
        return None
    if user.is_superuser:
        return Grants(superuser=True)
    everywhere, on_printer = None, {}
    rows = PrinterRole.objects.filter(user=user).values_list("printer_id", "role")
    for printer_id, role in rows:
        if printer_id is None:
            everywhere = role
        else:
            on_printer[printer_id] = role
    return Grants(everywhere, on_printer, staff=user.is_staff)


def role_of(
    user: AbstractBaseUser | AnonymousUser, printer: Printer | None
) -> int | None:
    """The highest role *user* holds on *printer* (None = on every printer)."""
    grants = grants_of(user)
    return None if grants is None else grants.on(printer)


def highest_role(user: AbstractBaseUser | AnonymousUser) -> int | None:
    """The highest role *user* holds on any printer (None: no role anywhere)."""
    if not user.is_authenticated or not user.is_active:
        return None
    if user.is_superuser:
        return Role.ADMIN
    best = max(
        PrinterRole.objects.filter(user=user).values_list("role", flat=True),
        default=None,
    )
    if best is None and user.is_staff:
        return Role.VIEWER
    return best


@dataclass
class Caller:
    """One client's context: what ESP3D attaches to every message it routes."""

    client: str
    user: AbstractBaseUser | AnonymousUser = field(default_factory=AnonymousUser)
    key: ApiKey | None = None
    address: str = ""

    @property
    def authenticated(self) -> bool:
        return bool(self.user.is_authenticated)

    @property
    def bound_printer_id(self) -> int | None:
        return self.key.printer_id if self.key else None

    @property
    def origin(self) -> str:
        """Who asked, as written on queued commands, jobs and the audit log."""
        who = getattr(self.user, "username", "") or "anonymous"
        via = f" key {self.key.prefix}" if self.key else ""
        at = f" {self.address}" if self.address else ""
        return f"{self.client}:{who}{via}{at}"[:100]

    def role(self, printer: Printer | None) -> int | None:
        """The user's role on *printer*, within what the key allows (printer, role)."""
        if not self._reaches(printer):
            return None
        return self._capped(role_of(self.user, printer))

    def _reaches(self, printer: Printer | None) -> bool:
        """The key is bound to no printer, or to this one."""
        bound = self.key.printer_id if self.key is not None else None
        return printer is None or bound in (None, printer.pk)

    def _capped(self, held: int | None) -> int | None:
        """*held*, at most the key's role."""
        cap = self.key.role if self.key is not None else None
        if held is None or cap is None:
            return held
        return min(held, cap)

    def can(self, printer: Printer | None, role: int) -> bool:
        held = self.role(printer)
        return held is not None and held >= role

    def require(self, printer: Printer | None, role: int) -> None:
        """Raise NotAuthenticated (401) or Forbidden (403) unless allowed."""
        if not self.authenticated:
            raise NotAuthenticated("log in or give an API key")
        if self.can(printer, role):
            return
        if (
            self.key is not None
            and printer is not None
            and self.key.printer_id
            not in (
                None,
                printer.pk,
            )
        ):
            raise Forbidden(
                f"this API key is bound to printer {self.key.printer.slug!r}"
            )
        cap = self.key.role if self.key is not None else None
        if cap is not None and cap < role:
            raise Forbidden(
                f"this API key may act as {Role(cap).label.split()[0]} at most;"
                f" {Role(role).label.split()[0]} role needed"
            )
        where = f"printer {printer.slug!r}" if printer else "every printer"
        raise Forbidden(
            f"{Role(role).label.split()[0]} role needed on {where}"
            f" (you have {Role(self.role(printer)).label.split()[0] if self.role(printer) else 'none'})"
        )

    def require_farm(self, role: int) -> None:
        """Raise unless the caller may act on the farm at *role*: the role on every
        printer (a farm job may go to any of them), with no key bound to one."""
        if not self.authenticated:
            raise NotAuthenticated("log in or give an API key")
        if self.key is not None and self.key.printer_id is not None:
            raise Forbidden(
                f"this API key is bound to printer {self.key.printer.slug!r}; the "
                "farm may give a job to any printer: use a key bound to none"
            )
        self.require(None, role)

    def printers(
        self, role: int = Role.VIEWER, *, fields: Collection[str] = ()
    ) -> list[Printer]:
        """The printers this caller may see (or act on at *role*): two queries
        however many printers there are (the user's roles are read once).

        *fields*: read only these columns (any other is read on first use, a query
        each printer).
        """
        grants = grants_of(self.user)
        if grants is None:
            return []
        found = Printer.objects.only(*fields) if fields else Printer.objects.all()
        if self.bound_printer_id is not None:
            found = found.filter(pk=self.bound_printer_id)
        allowed = []
        for printer in found:
            held = self._capped(grants.on(printer))
            if held is not None and held >= role:
                allowed.append(printer)
        return allowed

    def default_printer(self, role: int = Role.OPERATOR) -> Printer | None:
        """Where an upload without a slug goes: the key's printer, else the user's default."""
        if self.key is not None and self.key.printer_id is not None:
            return self.key.printer
        profile = getattr(self.user, "printhost", None) if self.authenticated else None
        if profile is not None and profile.default_printer_id is not None:
            return profile.default_printer
        allowed = self.printers(role)
        return allowed[0] if len(allowed) == 1 else None


def caller_from_request(request: HttpRequest, *, client: str = "http") -> Caller:
    """The caller of an HTTP request: its API key if it gives one, else its session.

    A key that matches nobody is an error (401), even when a session is present, so
    a mistyped key in a slicer never silently runs as someone else.
    """
    address = request.META.get("REMOTE_ADDR", "")
    raw = key_from_request(request)
    if raw is not None:
        key = find_key(raw)
        if key is None:
            raise NotAuthenticated("invalid or revoked API key")
        return Caller(client=client, user=key.user, key=key, address=address)
    user = getattr(request, "user", None) or AnonymousUser()
    return Caller(client=client, user=user, address=address)


def caller_from_key(raw: str, *, client: str, address: str = "") -> Caller | None:
    """The caller a raw key names (websocket query string, terminal first line)."""
    key = find_key(raw)
    if key is None:
        return None
    return Caller(client=client, user=key.user, key=key, address=address)


def admin_caller(request: HttpRequest) -> Caller:
    """The caller behind a Django admin action."""
    return Caller(
        client="admin", user=request.user, address=request.META.get("REMOTE_ADDR", "")
    )
