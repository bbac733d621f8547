"""A 1 GB upload through the resumable API keeps daphne's memory small.

daphne gives the application a request's whole body at once (it queues every chunk
before Django reads any), so one request costs its size in server memory; Django then
spools it to a temporary file. A big file therefore arrives as PATCHes of a few MB,
and the server's peak RSS (`VmHWM`) stays far below the file's size.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import TYPE_CHECKING

import httpx
import pytest

from tests.hosts import Host

if TYPE_CHECKING:
    from collections.abc import Iterator

pytestmark = pytest.mark.slow

SIZE = 1024**3
PATCH_BYTES = 16 * 1024**2
RSS_LIMIT = 150 * 1024**2


def gcode_stream(size: int) -> Iterator[bytes]:
    """*size* bytes of G-code in 1 MiB pieces; never more than one piece in memory."""
    line = b"G1 X10.000 Y20.000 E0.01000 ;" + b"-" * 480 + b"\n"
    block = line * ((1 << 20) // len(line))
    block += b";" * ((1 << 20) - len(block) - 1) + b"\n"
    sent = 0
    number = 0
    while sent < size:
        piece = b"; piece %010d\n" % number + block[15:]
        piece = piece[: size - sent]
        sent += len(piece)
        number += 1
        yield piece


def patches(size: int) -> Iterator[bytes]:
    """The stream regrouped into PATCH bodies of PATCH_BYTES."""
    pending: list[bytes] = []
    held = 0
    for piece in gcode_stream(size):
        pending.append(piece)
        held += len(piece)
        if held >= PATCH_BYTES:
            yield b"".join(pending)
            pending, held = [], 0
    if pending:
        yield b"".join(pending)


def daphne_pid(runhost: int) -> int:
    """daphne among runhost's children, found by its command line."""
    for child in Path(f"/proc/{runhost}/task/{runhost}/children").read_text().split():
        command = Path(f"/proc/{child}/cmdline").read_bytes().split(b"\0")
        if b"daphne" in command:
            return int(child)
    raise AssertionError("no daphne process under runhost")


def peak_rss(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise AssertionError("no VmHWM")


def test_one_gigabyte_upload_keeps_daphne_under_150_mb(tmp_path: Path) -> None:
    host = Host(tmp_path)
    host.env["PRINTHOST_MAX_JOB_BYTES"] = str(2 * SIZE)
    host.manage("migrate", "--noinput")
    host.shell(
        "from printers.models import Printer; Printer.objects.create("
        "name='Big', slug='big', port='/nonexistent', enabled=False)"
    )
    key = host.add_user("op", role="operator")
    digest = hashlib.sha256()
    with host.running() as runhost:
        client = httpx.Client(
            base_url=host.url, headers={"X-Api-Key": key}, timeout=300
        )
        response = client.post(
            "/printer/upload/big",
            params={"name": "huge.gcode", "size": SIZE, "autostart": "0"},
        )
        assert response.status_code == 201, response.text
        path = response.headers["Location"]
        offset = 0
        for body in patches(SIZE):
            digest.update(body)
            response = client.patch(
                path, content=body, headers={"Upload-Offset": str(offset)}
            )
            assert response.status_code == 200, response.text
            offset += len(body)
            assert int(response.headers["Upload-Offset"]) == offset
        job = response.json()["data"]["job"]
        peak = peak_rss(daphne_pid(runhost.pid))
    assert job["size"] == SIZE
    assert job["sha256"] == digest.hexdigest()
    assert job["state"] == "stored"
    print(
        f"daphne peak RSS {peak / 1024**2:.0f} MB for a {SIZE / 1024**3:.2f} GiB upload"
    )
    assert peak < RSS_LIMIT, f"daphne peaked at {peak / 1024**2:.0f} MB"
