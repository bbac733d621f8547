# ruff: noqa: F811 (the tests take the fixture `served`, imported, as an argument)
"""Uploads without good credentials are refused before their body is read, against a
running printhost; with a key or a browser session they get `100 Continue` and are
stored."""

from __future__ import annotations

import re

import httpx
import pytest

from tests.conftest import wait_for
from tests.security.body_limit_helpers import (
    BIG,
    JOB_CAP,
    SLACK,
    Served,
    chunked,
    exchange,
    job_files,
    multipart,
    served,  # noqa: F401 (a fixture)
    spool_is_empty,
    zeros,
)

pytestmark = pytest.mark.slow


#: Every upload route: (method, target) as a slicer or script sends it.
UPLOAD_TARGETS = [
    ("POST", "/printer/job/p1?a=upload"),
    ("POST", "/printer/job/p1?a=append&id=1"),
    ("POST", "/printer/model/p1"),
    ("PATCH", "/printer/upload/p1/1"),
    ("POST", "/api/files/local"),
    ("POST", "/p/p1/api/files/local"),
    ("POST", "/server/files/upload"),
    ("POST", "/p/p1/server/files/upload"),
]


@pytest.mark.parametrize(("method", "target"), UPLOAD_TARGETS)
def test_an_upload_without_credentials_gets_401_before_its_body_is_sent(
    served: Served, method: str, target: str
) -> None:
    answer = exchange(
        served.host.port,
        [f"{method} {target} HTTP/1.1", f"Content-Length: {JOB_CAP}"],
        zeros(JOB_CAP),
        expect=True,
    )
    assert answer.status == 401, answer
    assert answer.interim == []
    assert answer.sent == 0
    assert answer.error == "authentication required: log in or give an API key"


def test_an_upload_without_credentials_and_without_expect_is_not_read_either(
    served: Served,
) -> None:
    for head, body in (
        (f"Content-Length: {JOB_CAP}", zeros(JOB_CAP)),
        ("Transfer-Encoding: chunked", chunked(BIG)),
    ):
        answer = exchange(
            served.host.port, ["POST /p/p1/server/files/upload HTTP/1.1", head], body
        )
        assert answer.status == 401, answer
        assert answer.sent < min(JOB_CAP, SLACK)
    wait_for(lambda: spool_is_empty(served), 30, "no body kept in the temp folder")


def test_an_upload_with_a_bad_key_or_session_gets_401_before_its_body_is_sent(
    served: Served,
) -> None:
    for credential in (
        "X-Api-Key: ph_notakeyatall000000000000",
        "Authorization: Bearer ph_notakeyatall000000000000",
        "Cookie: sessionid=notasessionatall",
    ):
        answer = exchange(
            served.host.port,
            [
                "POST /api/files/local HTTP/1.1",
                credential,
                f"Content-Length: {JOB_CAP}",
            ],
            zeros(JOB_CAP),
            expect=True,
        )
        assert answer.status == 401, (credential, answer)
        assert answer.interim == []
        assert answer.sent == 0


def test_a_keyed_upload_gets_100_continue_and_is_stored(served: Served) -> None:
    content = b"G28\nG1 X10 Y10\n" * 1000
    kind, body = multipart("gated.gcode", content)
    answer = exchange(
        served.host.port,
        [
            "POST /api/files/local?apikey=" + served.key + " HTTP/1.1",
            f"Content-Type: {kind}",
            f"Content-Length: {len(body)}",
        ],
        [body],
        expect=True,
    )
    assert answer.interim == [100]
    assert answer.status == 201, answer
    assert content in job_files(served).values()


def test_a_browser_session_gets_100_continue_and_its_upload_is_stored(
    served: Served,
) -> None:
    with httpx.Client(base_url=served.host.url, timeout=30) as browser:
        form = browser.get("/accounts/login/")
        token = re.search(r'name="csrfmiddlewaretoken" value="([^"]+)"', form.text)
        assert token is not None
        logged_in = browser.post(
            "/accounts/login/",
            data={
                "username": "op",
                "password": "op",
                "csrfmiddlewaretoken": token.group(1),
            },
        )
        assert logged_in.status_code == 302, logged_in.text
        session = browser.cookies["sessionid"]
        csrf = browser.cookies["csrftoken"]
    content = b"G28\n; from a browser\n" * 100
    kind, body = multipart("browser.gcode", content)
    answer = exchange(
        served.host.port,
        [
            "POST /api/files/local HTTP/1.1",
            f"Cookie: sessionid={session}; csrftoken={csrf}",
            f"X-CSRFToken: {csrf}",
            f"Origin: {served.host.url}",
            f"Referer: {served.host.url}/",
            f"Content-Type: {kind}",
            f"Content-Length: {len(body)}",
        ],
        [body],
        expect=True,
    )
    assert answer.interim == [100]
    assert answer.status == 201, answer
    assert content in job_files(served).values()
