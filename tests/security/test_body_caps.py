# ruff: noqa: F811 (the tests take the fixture `served`, imported, as an argument)
"""Bodies over a cap are refused while they are sent, against a running printhost.

The attacks of issue 8 over a raw socket to daphne (`printhost.serve` under runhost):
a 400 MB anonymous POST to a route that takes no upload, an endless chunked body, an
upload over the job cap, too many uploads at once, an upload bigger than the free
space, a refused PATCH of a resumable upload. Each gets its answer while the client
is still sending (or before, with `Expect: 100-continue`), the client gets to send a
bounded amount, and nothing is left in the server's temporary folder or the job
storage.
"""

from __future__ import annotations

import contextlib
import socket
from typing import TYPE_CHECKING

import httpx
import pytest

from tests.conftest import wait_for
from tests.hosts import Host
from tests.security.body_limit_helpers import (
    BIG,
    JOB_CAP,
    SLACK,
    SMALL_CAP,
    Served,
    chunked,
    exchange,
    job_files,
    multipart,
    served,  # noqa: F401 (a fixture)
    spool_is_empty,
    zeros,
)

if TYPE_CHECKING:
    from pathlib import Path

pytestmark = pytest.mark.slow


def test_a_400_mb_anonymous_post_to_a_route_without_uploads_is_refused_unread(
    served: Served,
) -> None:
    answer = exchange(
        served.host.port,
        ["POST /api/version HTTP/1.1", f"Content-Length: {BIG}"],
        zeros(BIG),
    )
    assert answer.status == 413, answer
    assert answer.error == (
        f"request body (not an upload) larger than {SMALL_CAP} bytes "
        "(PRINTHOST_MAX_BODY_BYTES)"
    )
    assert answer.sent < SLACK
    wait_for(lambda: spool_is_empty(served), 30, "no body kept in the temp folder")


def test_an_endless_chunked_body_is_refused_once_it_crosses_the_small_cap(
    served: Served,
) -> None:
    answer = exchange(
        served.host.port,
        ["POST /api/version HTTP/1.1", "Transfer-Encoding: chunked"],
        chunked(BIG),
    )
    assert answer.status == 413, answer
    assert SMALL_CAP < answer.sent < SMALL_CAP + SLACK
    wait_for(lambda: spool_is_empty(served), 30, "no body kept in the temp folder")


def test_an_upload_over_the_job_cap_is_refused_while_it_streams_and_nothing_is_kept(
    served: Served,
) -> None:
    content = b"G28\n" * 1000
    kind, body = multipart("kept.gcode", content)
    stored = exchange(
        served.host.port,
        [
            "POST /api/files/local HTTP/1.1",
            f"X-Api-Key: {served.key}",
            f"Content-Type: {kind}",
            f"Content-Length: {len(body)}",
        ],
        [body],
    )
    assert stored.status == 201, stored
    before = job_files(served)

    declared = exchange(
        served.host.port,
        [
            "POST /printer/job/p1?a=upload HTTP/1.1",
            f"X-Api-Key: {served.key}",
            f"Content-Length: {JOB_CAP + 1}",
        ],
        zeros(JOB_CAP + 1),
    )
    assert declared.status == 413, declared
    assert declared.error == (
        f"job file larger than {JOB_CAP} bytes (PRINTHOST_MAX_JOB_BYTES)"
    )
    assert declared.sent < SLACK

    streamed = exchange(
        served.host.port,
        [
            "POST /server/files/upload HTTP/1.1",
            f"Authorization: Bearer {served.key}",
            "Transfer-Encoding: chunked",
        ],
        chunked(BIG),
    )
    assert streamed.status == 413, streamed
    assert JOB_CAP < streamed.sent < JOB_CAP + SLACK
    wait_for(lambda: spool_is_empty(served), 30, "no body kept in the temp folder")
    assert job_files(served) == before


def test_uploads_in_flight_are_capped_per_user(served: Served) -> None:
    held: list[socket.socket] = []
    head = [
        "PATCH /printer/upload/p1/1 HTTP/1.1",
        f"X-Api-Key: {served.key}",
        "Content-Length: 1000",
    ]
    try:
        for _ in range(2):
            first = exchange(
                served.host.port, head, expect=True, keep=held, stop_at_continue=True
            )
            assert first.interim == [100], first
        third = exchange(served.host.port, head, zeros(1000), expect=True)
        assert third.status == 429, third
        assert "at most 2" in third.error
        held.pop().close()

        def another_is_let_in() -> bool:
            answer = exchange(
                served.host.port, head, expect=True, keep=held, stop_at_continue=True
            )
            if answer.interim == [100]:
                return True
            held.pop().close()
            return False

        wait_for(another_is_let_in, 30, "a slot given back when an upload ends")
    finally:
        for sock in held:
            with contextlib.suppress(OSError):
                sock.close()


def test_an_upload_bigger_than_the_free_space_gets_507(tmp_path: Path) -> None:
    host = Host(tmp_path)
    host.env["PRINTHOST_UPLOAD_SPARE_BYTES"] = str(10**18)
    host.migrate()
    key = host.add_user("op", superuser=True)
    with host.running():
        answer = exchange(
            host.port,
            [
                "POST /api/files/local HTTP/1.1",
                f"X-Api-Key: {key}",
                "Content-Length: 1000",
            ],
            zeros(1000),
            expect=True,
        )
        streamed = exchange(
            host.port,
            [
                "POST /server/files/upload HTTP/1.1",
                f"X-Api-Key: {key}",
                "Transfer-Encoding: chunked",
            ],
            chunked(BIG),
            expect=True,
        )
        anonymous = exchange(
            host.port,
            ["POST /api/files/local HTTP/1.1", "Content-Length: 1000"],
            zeros(1000),
            expect=True,
        )
    assert answer.status == 507, answer
    assert answer.error.startswith("not enough space for this upload: 1000 bytes")
    assert answer.sent == 0
    assert streamed.status == 507, streamed
    assert streamed.error.startswith("not enough space for uploads:")
    assert streamed.sent == 0
    assert anonymous.status == 401


def test_a_refused_patch_leaves_its_resumable_upload_as_it_was(served: Served) -> None:
    with httpx.Client(
        base_url=served.host.url, headers={"X-Api-Key": served.key}, timeout=30
    ) as client:
        opened = client.post(
            "/printer/upload/p1", params={"name": "resumed.gcode", "size": 4000}
        )
        assert opened.status_code == 201, opened.text
        where = opened.headers["Location"]
        first = client.patch(
            where, content=b"G28\n" * 500, headers={"Upload-Offset": "0"}
        )
        assert first.headers["Upload-Offset"] == "2000", first.text
        for head, body in (
            (f"Content-Length: {JOB_CAP + 1}", zeros(JOB_CAP + 1)),
            ("Transfer-Encoding: chunked", chunked(BIG)),
        ):
            refused = exchange(
                served.host.port,
                [
                    f"PATCH {where} HTTP/1.1",
                    f"X-Api-Key: {served.key}",
                    "Upload-Offset: 2000",
                    head,
                ],
                body,
            )
            assert refused.status == 413, refused
        assert client.head(where).headers["Upload-Offset"] == "2000"
        last = client.patch(
            where, content=b"G1 X1\n" * 333 + b"\n\n", headers={"Upload-Offset": "2000"}
        )
        assert last.status_code == 200, last.text
        assert last.json()["data"]["complete"] is True
    wait_for(lambda: spool_is_empty(served), 30, "no body kept in the temp folder")
    assert b"G28\n" * 500 + b"G1 X1\n" * 333 + b"\n\n" in job_files(served).values()


def test_an_upload_from_who_may_upload_nowhere_is_refused_before_its_body(
    served: Served,
) -> None:
    """A viewer's key: 403 instead of `100 Continue`, and once a body streaming
    without Expect is larger than one that is not an upload; nothing is kept. The
    route's other calls, with their small bodies, are answered as before."""
    viewer = served.host.add_user("watcher", "viewer", printer="p1")
    before = job_files(served)
    head = [
        "POST /printer/job/p1?a=upload HTTP/1.1",
        f"X-Api-Key: {viewer}",
        f"Content-Length: {JOB_CAP}",
    ]
    asked = exchange(served.host.port, head, zeros(JOB_CAP), expect=True)
    assert asked.status == 403, asked
    assert asked.interim == []  # never told to send the body
    assert asked.error == "uploading a job needs the operator role on a printer"
    farm = exchange(
        served.host.port,
        ["POST /printer/job/farm?a=upload HTTP/1.1", f"Authorization: Bearer {viewer}",
         "Transfer-Encoding: chunked"],
        chunked(BIG),
    )  # fmt: skip
    assert farm.status == 403, farm
    assert farm.sent < SLACK
    form = b"a=list"
    listed = exchange(
        served.host.port,
        ["POST /printer/job/p1 HTTP/1.1", f"X-Api-Key: {viewer}",
         "Content-Type: application/x-www-form-urlencoded",
         f"Content-Length: {len(form)}"],
        [form],
    )  # fmt: skip
    assert listed.status == 200, listed
    wait_for(lambda: spool_is_empty(served), 30, "no body kept in the temp folder")
    assert job_files(served) == before
