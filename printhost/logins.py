"""Password logins, throttled per user name and per address on every path.

Every password check goes through `ThrottledModelBackend` (the only backend in
AUTHENTICATION_BACKENDS), so the UI login page, the Django admin's login and
OctoPrint's `/api/login` are all throttled the same way:

1. Before the password is checked: if the user name has `PRINTHOST_LOGIN_USER_FAILURES`
   failures, or the address `PRINTHOST_LOGIN_ADDRESS_FAILURES`, within the last
   `PRINTHOST_LOGIN_WINDOW_SECONDS`, the attempt is refused (even with the right
   password) and logged. Refused attempts are not counted, so the lock lifts when
   the window has passed over the failures that caused it.
2. A wrong password (or an unknown user name: whether a user exists is never
   told) is stored as a `LoginFailure`.
3. A right password clears the user name's failures.

The counts live in the database: printhost has no shared cache by default, and
every daphne process (and every host on one database) must see the same counts.
"""

from __future__ import annotations

import logging
from datetime import timedelta
from typing import TYPE_CHECKING, Any

from django import forms
from django.conf import settings
from django.contrib.admin.forms import AdminAuthenticationForm
from django.contrib.auth.backends import ModelBackend
from django.contrib.auth.forms import AuthenticationForm
from django.contrib.auth.views import LoginView
from django.core.exceptions import PermissionDenied
from django.utils import timezone

from printhost.models import LoginFailure

if TYPE_CHECKING:
    from django.http import HttpRequest, HttpResponse

log = logging.getLogger("printhost.auth")

THROTTLED_MESSAGE = (
    "Too many failed logins for this user name or from this address: "
    "wait {minutes} minutes and try again."
)


class Throttled(PermissionDenied):
    """Too many recent failures for this user name or address (HTTP 429)."""


def _name(username: object) -> str:
    return str(username or "").strip().casefold()[:150]


def address_of(request: HttpRequest | None) -> str:
    if request is None:
        return ""
    return str(request.META.get("REMOTE_ADDR", ""))[:64]


def window() -> timedelta:
    return timedelta(seconds=settings.PRINTHOST_LOGIN_WINDOW_SECONDS)


def throttled_message() -> str:
    minutes = max(1, round(settings.PRINTHOST_LOGIN_WINDOW_SECONDS / 60))
    return THROTTLED_MESSAGE.format(minutes=minutes)


def check(username: object, request: HttpRequest | None) -> None:
    """Raise Throttled (and log it) if this user name or address is locked out."""
    name, address = _name(username), address_of(request)
    recent = LoginFailure.objects.filter(time__gte=timezone.now() - window())
    by_user = recent.filter(username=name).count()
    by_address = recent.filter(address=address).count() if address else 0
    user_limit = settings.PRINTHOST_LOGIN_USER_FAILURES
    address_limit = settings.PRINTHOST_LOGIN_ADDRESS_FAILURES
    if by_user >= user_limit or by_address >= address_limit:
        log.warning(
            "login throttled: user %r from %s (%d failures for the user, %d from the"
            " address in %d s)",
            name,
            address or "an unknown address",
            by_user,
            by_address,
            settings.PRINTHOST_LOGIN_WINDOW_SECONDS,
        )
        raise Throttled(throttled_message())


def failed(username: object, request: HttpRequest | None) -> None:
    """Count a failure; drop the rows no window looks at any more."""
    LoginFailure.objects.filter(time__lt=timezone.now() - window()).delete()
    LoginFailure.objects.create(username=_name(username), address=address_of(request))


def succeeded(username: object) -> None:
    LoginFailure.objects.filter(username=_name(username)).delete()


class ThrottledModelBackend(ModelBackend):
    """Django's user and password check, behind the throttle (see the module)."""

    def authenticate(
        self,
        request: HttpRequest | None,
        username: str | None = None,
        password: str | None = None,
        **kwargs: Any,
    ) -> Any:
        if username is None:
            username = kwargs.get("username", "")
        check(username, request)
        user = super().authenticate(
            request, username=username, password=password, **kwargs
        )
        if user is None:
            failed(username, request)
        else:
            succeeded(username)
        return user


class _ThrottleMessage:
    """Say "too many attempts" instead of "wrong password" when locked out."""

    request: HttpRequest | None

    def clean(self) -> dict[str, Any]:
        data: dict[str, Any] = self.cleaned_data  # type: ignore[attr-defined]
        try:
            check(data.get("username"), self.request)
        except Throttled as error:
            self.throttled = True
            raise forms.ValidationError(str(error), code="throttled") from None
        return super().clean()  # type: ignore[misc]


class ThrottledLoginForm(_ThrottleMessage, AuthenticationForm):
    throttled = False


class ThrottledAdminLoginForm(_ThrottleMessage, AdminAuthenticationForm):
    throttled = False


class ThrottledLoginView(LoginView):
    """The UI's login page: 429 with the form's message while locked out."""

    authentication_form = ThrottledLoginForm

    def form_invalid(self, form: forms.Form) -> HttpResponse:
        response = super().form_invalid(form)
        if getattr(form, "throttled", False):
            response.status_code = 429
        return response
