"""Port URLs over real HTTP to a running printhost, and a bad stored port never opened."""

from __future__ import annotations

from typing import TYPE_CHECKING

import httpx
import pytest

from tests.conftest import wait_for
from tests.hosts import Host

if TYPE_CHECKING:
    from pathlib import Path

pytestmark = pytest.mark.slow


def test_port_urls_are_refused_over_http_and_never_opened(tmp_path: Path) -> None:
    host = Host(tmp_path)
    host.migrate()
    host.add_simulated_printer("mk3")
    spied = tmp_path / "spied.txt"
    link = tmp_path / "mk3.tty"
    host.shell(
        "from printers.models import Printer; Printer.objects.create(name='Evil', "
        f"slug='evil', port='spy://{link}?file={spied}', temperature_interval=0)"
    )
    root = host.add_user("root", superuser=True)
    boss = host.add_user("boss", role="admin", printer="mk3")
    with host.running():
        web = httpx.Client(base_url=host.url, timeout=30)
        as_root, as_boss = {"X-Api-Key": root}, {"X-Api-Key": boss}
        for port in (
            f"spy://{link}?file={spied}",
            "loop://",
            "hwgrep://.*",
            "socket://127.0.0.1:6379",
            "rfc2217://127.0.0.1:5432",
            "/etc/passwd",
        ):
            response = web.patch(
                "/printer/config/mk3", json={"port": port}, headers=as_root
            )
            assert response.status_code == 400, (port, response.text)
            assert "port" in response.json()["error"], response.text
        response = web.patch(
            "/printer/config/mk3", json={"port": "/dev/ttyUSB0"}, headers=as_boss
        )
        assert response.status_code == 403, response.text
        assert "needs a superuser" in response.json()["error"]
        response = web.patch(
            "/printer/config/mk3", json={"auto_start": True}, headers=as_boss
        )
        assert response.status_code == 200, response.text

        def evil_message() -> str:
            state = web.get("/printer/state/evil", headers=as_root)
            return str(state.json()["data"])

        wait_for(
            lambda: "spy:// ports are not allowed" in evil_message(),
            60,
            "the worker to refuse the stored spy:// port",
        )
        assert web.get("/printer/config/mk3", headers=as_root).json()["data"][
            "port"
        ] == str(link)
    assert not spied.exists()
