"""The web server while PostgreSQL is away: every request that needs the database
gets 503 with Retry-After and a message saying the database is not reachable (not a
bare 500), and the same requests work again once it is back."""

from __future__ import annotations

from typing import TYPE_CHECKING
from urllib.parse import urlparse

import httpx
import pytest

from tests.conftest import wait_for
from tests.hosts import Host, postgres_url
from tests.netfault import TcpProxy

if TYPE_CHECKING:
    from pathlib import Path

pytestmark = [pytest.mark.slow, pytest.mark.services]


def test_requests_get_503_while_the_database_is_away_and_work_once_it_is_back(
    tmp_path: Path,
):
    direct = postgres_url()
    setup = Host(tmp_path, direct)
    setup.migrate()
    key = setup.add_user("operator", "operator")
    proxy = TcpProxy(("127.0.0.1", 5432))
    host = Host(tmp_path, proxy.url("postgresql", urlparse(direct).path,
                                    user="postgres"))  # fmt: skip
    try:
        with (
            host.running("--no-workers"),
            httpx.Client(
                base_url=host.url, headers={"X-Api-Key": key}, timeout=30
            ) as client,
        ):
            assert client.get("/printer/list").status_code == 200
            _log_in(client, "operator")
            assert client.get("/history/").status_code == 200
            proxy.cut()
            api = client.get("/printer/list")
            write = client.post("/printer/bedclear/nonesuch")
            page = client.get("/history/", headers={"Accept": "text/html"})
            proxy.restore()
            wait_for(
                lambda: client.get("/printer/list").status_code == 200,
                30, "the API to answer again",
            )  # fmt: skip
    finally:
        proxy.close()

    for answer in (api, write):
        assert answer.status_code == 503, answer.text
        assert "database is not reachable" in answer.json()["error"]
        assert answer.headers["Retry-After"] == "5"
    assert page.status_code == 503
    assert page.headers["Content-Type"].startswith("text/plain")
    assert "database is not reachable" in page.text
    log = host.log_tail(400)
    assert "Service Unavailable: /printer/list" in log


def _log_in(client: httpx.Client, username: str) -> None:
    """A browser's session: the login form, with its CSRF token."""
    client.get("/accounts/login/")
    token = client.cookies["csrftoken"]
    answer = client.post(
        "/accounts/login/",
        data={"username": username, "password": username,
              "csrfmiddlewaretoken": token},
        headers={"Referer": f"{client.base_url}accounts/login/"},
    )  # fmt: skip
    assert answer.status_code == 302, answer.text
