"""Helpers of the request-body tests: a printhost served with small caps, raw HTTP
exchanges with it over a socket, and bodies to send."""

from __future__ import annotations

import json
import select
import socket
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import pytest

from tests.hosts import Host

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator
    from pathlib import Path


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
