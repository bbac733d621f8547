"""Approving Cura's app-key request in the browser: where it came from, which printer,
which role (never above the approver's own).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import httpx
import pytest

from tests.ui.conftest import OPERATOR, LiveHost, log_in, start_live_host

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

    from tests.ui.conftest import Tab

pytestmark = pytest.mark.slow

#: httpx's default of 5 s is short for a live host's first request on a busy machine.
TIMEOUT = 30.0


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveHost]:
    folder = tmp_path_factory.mktemp("browser-pairing")
    yield from start_live_host(folder, {"mk3": "", "mini": ""})


def cura_asks(live: LiveHost) -> str:
    """Cura's request through the printer-less URL; returns the URL it polls."""
    asked = httpx.post(
        f"{live.url}/plugin/appkeys/request", json={"app": "Cura"}, timeout=TIMEOUT
    )
    assert asked.status_code == 201, asked.text
    return asked.headers["Location"]


def test_an_operator_approves_a_viewer_key_bound_to_one_printer(
    live: LiveHost, open_tab: Callable[..., Tab]
) -> None:
    from playwright.sync_api import expect

    poll = cura_asks(live)
    tab = open_tab(live.url, "tablet")
    log_in(tab, OPERATOR, "/account/")
    page = tab.page
    request = page.locator("[data-test=appkey]")
    expect(request.locator("[data-test=appkey-from]")).to_contain_text(
        "Cura from 127.0.0.1"
    )
    request.locator("[data-test=appkey-printer]").select_option("mini")
    # Above the approver's own role: refused, said so, and the request still waits.
    tab.allow_console("status of 403")
    request.locator("[data-test=appkey-role]").select_option("admin")
    request.locator("[data-test=appkey-approve]").click()
    expect(page.locator("[data-test=error]")).to_contain_text("at most your own role")
    assert httpx.get(poll, timeout=TIMEOUT).status_code == 202

    request.locator("[data-test=appkey-role]").select_option("viewer")
    request.locator("[data-test=appkey-approve]").click()
    expect(page.locator("[data-test=appkey]")).to_have_count(0)
    expect(page.locator("[data-test=keys]")).to_contain_text("Cura (app key)")
    granted = httpx.get(poll, timeout=TIMEOUT)
    assert granted.status_code == 200, granted.text
    app = httpx.Client(
        base_url=live.url, headers={"X-Api-Key": granted.json()["api_key"]}
    )
    assert app.get("/printer/state/mini").status_code == 200
    assert app.get("/printer/state/mk3").status_code == 403  # bound to mini
    assert app.post("/printer/bedclear/mini").status_code == 403  # a viewer's key
