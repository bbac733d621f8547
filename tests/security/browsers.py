"""A person in a browser, for tests against a running printhost: log in, log out."""

from __future__ import annotations

import httpx

from tests.hosts import Host


def browser_login(host: Host, username: str, password: str = "") -> httpx.Client:
    """A browser session: the login form with its CSRF token, as a person would.

    The password is the user name unless given (`Host.add_user`'s convention).
    """
    browser = httpx.Client(base_url=host.url, timeout=30)
    browser.get("/accounts/login/")
    answer = browser.post(
        "/accounts/login/",
        data={
            "username": username,
            "password": password or username,
            "csrfmiddlewaretoken": browser.cookies["csrftoken"],
        },
    )
    assert answer.status_code == 302, answer.text
    assert "sessionid" in browser.cookies
    return browser


def browser_logout(browser: httpx.Client) -> None:
    """The page's "Log out" button: a POST with the CSRF token."""
    answer = browser.post(
        "/accounts/logout/",
        data={"csrfmiddlewaretoken": browser.cookies["csrftoken"]},
    )
    assert answer.status_code in (200, 302), answer.text
