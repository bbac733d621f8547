"""Cross-site requests against a running printhost: a link must not drive the printer.

A logged-in operator's browser follows any link or image on any page, with its
session cookie. So with a session, every call that changes something needs POST
and a CSRF token; GET acts only for API-key callers (Repetier-Server's API and the
slicers that speak it need that). Real HTTP (httpx) against `runhost`, onto a
simulated Marlin printer.
"""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import pytest

from tests.conftest import wait_for
from tests.hosts import Host
from tests.security.browsers import browser_login

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def host(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Host]:
    host = Host(tmp_path_factory.mktemp("csrf"))
    host.migrate()
    host.add_simulated_printer("mk3")
    host.env["TEST_OPERATOR_KEY"] = host.add_user("op", role="operator")
    with host.running():
        client = keyed(host)
        wait_for(
            lambda: client.get("/printer/state/mk3").json()["data"]["state"] == "idle",
            60,
            "the printer to connect",
        )
        yield host


def keyed(host: Host) -> httpx.Client:
    """A program with the operator's API key (a slicer, a script)."""
    key = host.env["TEST_OPERATOR_KEY"]
    return httpx.Client(base_url=host.url, headers={"X-Api-Key": key}, timeout=30)


def queued(host: Host, text: str) -> int:
    return host.query(
        f"SELECT count(*) FROM printers_queuedcommand WHERE text = '{text}'"
    )[0][0]


def test_a_link_cannot_make_a_logged_in_browser_heat_the_hotend(host: Host) -> None:
    browser = browser_login(host, "op")
    attacks = [
        "/printer/send/mk3?cmd=M104 S300",
        '/printer/api/mk3?a=send&data={"cmd": "M104 S300"}',
    ]
    for url in attacks:
        answer = browser.get(url)
        assert answer.status_code == 403, f"{url}: {answer.status_code} {answer.text}"
        assert "POST" in answer.json()["error"]
    assert queued(host, "M104 S300") == 0


def test_a_link_cannot_control_jobs_through_a_browser_session(host: Host) -> None:
    browser = browser_login(host, "op")
    for action in ("start&id=1", "pause", "resume", "abort", "delete&id=1", "create"):
        answer = browser.get(f"/printer/job/mk3?a={action}")
        assert answer.status_code == 403, f"{action}: {answer.text}"
    for call in ("stopJob", "continueJob"):
        answer = browser.get(f"/printer/api/mk3?a={call}")
        assert answer.status_code == 403, f"{call}: {answer.text}"
    # Reading is still fine with a session.
    assert browser.get("/printer/job/mk3?a=list").status_code == 200
    assert browser.get("/printer/api/mk3?a=listJobs").status_code == 200


def test_a_session_post_without_a_csrf_token_is_refused(host: Host) -> None:
    browser = browser_login(host, "op")
    answer = browser.post("/printer/send/mk3", data={"cmd": "M104 S299"})
    assert answer.status_code == 403, answer.text
    assert "CSRF" in answer.json()["error"]
    assert queued(host, "M104 S299") == 0


def test_a_session_post_with_the_csrf_token_sends_the_command(host: Host) -> None:
    browser = browser_login(host, "op")
    answer = browser.post(
        "/printer/send/mk3",
        data={"cmd": "M104 S0"},
        headers={"X-CSRFToken": browser.cookies["csrftoken"]},
    )
    assert answer.status_code == 200, answer.text
    assert queued(host, "M104 S0") >= 1


def test_api_key_callers_may_still_act_with_get_as_repetier_clients_do(
    host: Host,
) -> None:
    client = keyed(host)
    answer = client.get("/printer/send/mk3", params={"cmd": "M104 S1"})
    assert answer.status_code == 200, answer.text
    answer = client.get(
        "/printer/api/mk3", params={"a": "send", "data": '{"cmd": "M104 S2"}'}
    )
    assert answer.status_code == 200, answer.text
    assert queued(host, "M104 S1") == 1
    assert queued(host, "M104 S2") == 1
    # ?apikey= in the URL is a key too (slicers that cannot set headers).
    plain = httpx.Client(base_url=host.url, timeout=30)
    key = host.env["TEST_OPERATOR_KEY"]
    answer = plain.get(f"/printer/send/mk3?cmd=M104 S3&apikey={key}")
    assert answer.status_code == 200, answer.text
