"""Password guessing is throttled per user name and per address, on every login path.

Real HTTP against a running printhost: the UI's login page, the Django admin's login
and OctoPrint's `/api/login` share one count (5 failures per user name, 20 per
address, in 15 minutes). Whether a user exists is never told.
"""

from __future__ import annotations

import secrets
from collections.abc import Iterator
from datetime import timedelta

import httpx
import pytest
from django.contrib.auth.password_validation import validate_password
from django.core.exceptions import ValidationError
from django.test import RequestFactory
from django.utils import timezone

from printhost import logins
from printhost.models import LoginFailure
from tests.hosts import Host

USER_LIMIT, ADDRESS_LIMIT = 5, 20


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Host]:
    host = Host(tmp_path_factory.mktemp("logins"))
    host.migrate()
    for name in ("ann", "bea", "cal"):
        host.add_user(name)
    host.add_user("root", superuser=True)
    with host.running():
        yield host


@pytest.fixture
def host(served: Host) -> Host:
    """The running host with no failures counted (each test starts afresh)."""
    served.query("DELETE FROM printhost_loginfailure")
    return served


def form_login(host: Host, username: str, password: str, path: str) -> httpx.Response:
    """One attempt through a login form, as a browser makes it."""
    browser = httpx.Client(base_url=host.url, timeout=30)
    browser.get(path)
    return browser.post(
        path,
        data={
            "username": username,
            "password": password,
            "csrfmiddlewaretoken": browser.cookies["csrftoken"],
        },
    )


def page_login(host: Host, username: str, password: str) -> httpx.Response:
    return form_login(host, username, password, "/accounts/login/")


def api_login(host: Host, username: str, password: str) -> httpx.Response:
    return httpx.post(
        f"{host.url}/api/login", json={"user": username, "pass": password}, timeout=30
    )


@pytest.mark.slow
def test_five_wrong_passwords_lock_the_user_out_even_with_the_right_one(
    host: Host,
) -> None:
    for _ in range(USER_LIMIT):
        assert page_login(host, "ann", "guess").status_code == 200
    locked = page_login(host, "ann", "ann")
    assert locked.status_code == 429
    assert "Too many failed logins" in locked.text
    assert "sessionid" not in locked.cookies
    assert "login throttled: user 'ann'" in host.log_tail(400)
    # Another user from the same address is not locked out by ann's failures.
    assert page_login(host, "bea", "bea").status_code == 302


@pytest.mark.slow
def test_an_unknown_user_name_is_answered_exactly_like_a_known_one(
    host: Host,
) -> None:
    answers = {}
    for name in ("ann", "nobody"):
        statuses = [page_login(host, name, "guess").status_code for _ in range(6)]
        answers[name] = (statuses, page_login(host, name, "x").text.count("Too many"))
    assert answers["ann"] == answers["nobody"] == ([200] * 5 + [429], 1)


@pytest.mark.slow
def test_a_successful_login_clears_the_users_failures(host: Host) -> None:
    for _ in range(USER_LIMIT - 1):
        page_login(host, "bea", "guess")
    assert page_login(host, "bea", "bea").status_code == 302
    for _ in range(USER_LIMIT - 1):
        page_login(host, "bea", "guess")
    assert page_login(host, "bea", "bea").status_code == 302


@pytest.mark.slow
def test_twenty_failures_from_one_address_lock_the_address_out(host: Host) -> None:
    for number in range(ADDRESS_LIMIT):
        assert page_login(host, f"guess{number}", "guess").status_code == 200
    assert page_login(host, "cal", "cal").status_code == 429
    assert api_login(host, "cal", "cal").status_code == 429


@pytest.mark.slow
def test_the_admin_login_and_the_octoprint_login_share_the_count(host: Host) -> None:
    for _ in range(2):
        assert api_login(host, "root", "guess").status_code == 401
    for _ in range(USER_LIMIT - 2):
        answer = form_login(host, "root", "guess", "/admin/login/")
        assert answer.status_code == 200
    admin = form_login(host, "root", "root", "/admin/login/")
    assert "Too many failed logins" in admin.text
    assert "sessionid" not in admin.cookies
    answer = api_login(host, "root", "root")
    assert answer.status_code == 429
    assert "Too many failed logins" in answer.json()["error"]


@pytest.mark.django_db
def test_the_lockout_lifts_when_the_window_has_passed_over_the_failures() -> None:
    request = RequestFactory().post("/accounts/login/", REMOTE_ADDR="10.0.0.9")
    for _ in range(USER_LIMIT):
        logins.failed("Dee", request)
    with pytest.raises(logins.Throttled):
        logins.check("dee", request)
    LoginFailure.objects.update(time=timezone.now() - timedelta(minutes=16))
    logins.check("dee", request)


def test_common_and_numeric_passwords_are_refused_and_demo_passwords_pass() -> None:
    for weak in ("password123", "12345678901", "qwertyuiop"):
        with pytest.raises(ValidationError):
            validate_password(weak)
    for _ in range(20):
        validate_password(secrets.token_urlsafe(9))  # setup_demo's admin password
