"""Request bodies are judged before they are read, against a running printhost.

The attacks of issue 8 over a raw socket to daphne (`printhost.serve` under runhost):
a 400 MB anonymous POST to a route that takes no upload, an endless chunked body, an
upload without (or with a bad) key, too many uploads at once, an upload bigger than
the free space. Each gets its answer while the client is still sending (or before,
with `Expect: 100-continue`), the client gets to send a bounded amount, and nothing
is left in the server's temporary folder or the job storage.
"""

from __future__ import annotations

import contextlib
import json
import re
import select
import socket
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import httpx
import pytest

from tests.conftest import wait_for
from tests.hosts import Host

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator
    from pathlib import Path

pytestmark = pytest.mark.slow

#: PRINTHOST_MAX_JOB_BYTES of the served host.
JOB_CAP = 8 * 1024**2
#: PRINTHOST_MAX_BODY_BYTES (the default).
SMALL_CAP = 1024**2
#: What a client may get to send past a cap before the answer stops it: the
#: kernel's socket buffers on both ends (generous; the body is 400 MB).
SLACK = 64 * 1024**2
BIG = 400 * 1000**2
PIECE = 64 * 1024


@dataclass
class Served:
    host: Host
    key: str
    spool: Path


@dataclass
class Answer:
    status: int = 0
    headers: dict[str, str] = field(default_factory=dict)
    body: bytes = b""
    interim: list[int] = field(default_factory=list)
    sent: int = 0

    @property
    def error(self) -> str:
        return json.loads(self.body)["error"]


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    folder = tmp_path_factory.mktemp("bodies")
    spool = folder / "tmp"
    spool.mkdir()
    host = Host(folder)
    host.env.update(
        TMPDIR=str(spool),
        PRINTHOST_MAX_JOB_BYTES=str(JOB_CAP),
        PRINTHOST_UPLOADS_PER_CALLER="2",
    )
    host.migrate()
    host.add_simulated_printer("p1")
    key = host.add_user("op", "operator", printer="p1")
    with host.running():
        yield Served(host, key, spool)


def _parse(data: bytes, answer: Answer) -> bytes | None:
    """Take interim answers off *data*; fill *answer* once the final one is whole."""
    while b"\r\n\r\n" in data:
        head, _, rest = data.partition(b"\r\n\r\n")
        lines = head.decode("latin-1").split("\r\n")
        status = int(lines[0].split()[1])
        if 100 <= status < 200:
            answer.interim.append(status)
            data = rest
            continue
        headers = {
            k.strip().lower(): v.strip()
            for k, _, v in (line.partition(":") for line in lines[1:])
        }
        length = int(headers.get("content-length", "0"))
        if len(rest) < length:
            return data
        answer.status, answer.headers, answer.body = status, headers, rest[:length]
        return None
    return data


def exchange(
    port: int,
    head: list[str],
    body: Iterable[bytes] = (),
    *,
    expect: bool = False,
    timeout: float = 60,
    keep: list[socket.socket] | None = None,
    stop_at_continue: bool = False,
) -> Answer:
    """Send *head*, then *body* piece by piece while watching for the answer.

    With *expect*, the body waits for `100 Continue`. Sending never blocks: when the
    server stops reading, the client still reads its answer. With *keep*, the socket
    is left open (appended to it) instead of closed.
    """
    answer = Answer()
    lines = [*head, f"Host: 127.0.0.1:{port}"] + (
        ["Expect: 100-continue"] if expect else []
    )
    sock = socket.create_connection(("127.0.0.1", port), timeout=10)
    sock.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
    sock.setblocking(False)
    pieces = iter(body)
    current = b""
    sending = not expect
    pending = b""
    deadline = time.monotonic() + timeout
    try:
        while True:
            assert time.monotonic() < deadline, f"no answer in {timeout} s: {answer}"
            readable, writable, _ = select.select(
                [sock], [sock] if sending else [], [], 1.0
            )
            if readable:
                try:
                    data = sock.recv(65536)
                except ConnectionError:
                    data = b""
                assert data or pending == b"", f"closed mid-answer: {pending!r}"
                assert data, f"closed without an answer after {answer.sent} bytes"
                left = _parse(pending + data, answer)
                if answer.status:
                    return answer
                pending = left or b""
                if answer.interim:
                    if stop_at_continue:
                        return answer
                    sending = True
                continue
            if writable:
                if not current:
                    current = next(pieces, b"")
                    if not current:
                        sending = False
                        continue
                try:
                    count = sock.send(current)
                except (BlockingIOError, InterruptedError):
                    continue
                except ConnectionError:
                    sending = False
                    continue
                answer.sent += count
                current = current[count:]
    finally:
        if keep is not None:
            keep.append(sock)
        else:
            sock.close()


def zeros(total: int) -> Iterator[bytes]:
    block = b"\0" * PIECE
    sent = 0
    while sent < total:
        yield block[: total - sent]
        sent += PIECE


def chunked(total: int) -> Iterator[bytes]:
    """A chunked body of *total* bytes (as good as endless), then its last chunk."""
    for piece in zeros(total):
        yield b"%x\r\n" % len(piece) + piece + b"\r\n"
    yield b"0\r\n\r\n"


def multipart(name: str, content: bytes) -> tuple[str, bytes]:
    boundary = "printhostboundary"
    body = (
        (
            f'--{boundary}\r\nContent-Disposition: form-data; name="file"; '
            f'filename="{name}"\r\nContent-Type: application/octet-stream\r\n\r\n'
        ).encode()
        + content
        + f"\r\n--{boundary}--\r\n".encode()
    )
    return f"multipart/form-data; boundary={boundary}", body


def spool_is_empty(served: Served) -> bool:
    return not any(served.spool.iterdir())


def job_files(served: Served) -> dict[str, bytes]:
    jobs = served.host.folder / "jobs"
    if not jobs.exists():
        return {}
    return {str(p): p.read_bytes() for p in jobs.rglob("*") if p.is_file()}


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
