"""Big uploads keep the web server's memory small, whatever the file's size.

daphne queues a request's whole body for the application at once; printhost's server
(`printhost.serve`) keeps all but 1 MB of it on disk until Django reads it, and
Django spools it to a temporary file. The server's peak RSS (`VmHWM`) must stay far
below the file's size both for a 1 GiB resumable upload (PATCHes of 16 MB) and for a
512 MiB upload in one multipart request, as slicers send them.
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
    """The web server among runhost's children, found by its command line."""
    for child in Path(f"/proc/{runhost}/task/{runhost}/children").read_text().split():
        command = Path(f"/proc/{child}/cmdline").read_bytes().split(b"\0")
        if b"printhost.serve" in command:
            return int(child)
    raise AssertionError("no web server process under runhost")


def peak_rss(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise AssertionError("no VmHWM")


def test_one_gigabyte_upload_keeps_daphne_under_150_mb(tmp_path: Path) -> None:
    host = Host(tmp_path)
    host.env["PRINTHOST_MAX_JOB_BYTES"] = str(2 * SIZE)
    host.migrate()
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


def test_half_a_gigabyte_multipart_upload_keeps_the_server_under_150_mb(
    tmp_path: Path,
) -> None:
    host = Host(tmp_path)
    host.migrate()
    host.shell(
        "from printers.models import Printer; Printer.objects.create("
        "name='Big', slug='big', port='/nonexistent', enabled=False)"
    )
    key = host.add_user("op", role="operator")
    size = 512 * 1024**2
    source = tmp_path / "slicer-output.gcode"
    digest = hashlib.sha256()
    with source.open("wb") as out:
        for piece in gcode_stream(size):
            digest.update(piece)
            out.write(piece)
    with host.running() as runhost, source.open("rb") as upload:
        # PrusaSlicer's OctoPrint upload: one multipart request (file, path, print).
        response = httpx.post(
            f"{host.url}/p/big/api/files/local",
            headers={"X-Api-Key": key},
            data={"path": "", "print": "false"},
            files={"file": ("big.gcode", upload, "application/octet-stream")},
            timeout=300,
        )
        peak = peak_rss(daphne_pid(runhost.pid))
    assert response.status_code == 201, response.text
    stored = host.query("SELECT size_bytes, sha256, state FROM jobs_job")
    assert stored == [(size, digest.hexdigest(), "stored")]
    print(
        f"server peak RSS {peak / 1024**2:.0f} MB for a {size / 1024**2:.0f} MiB multipart upload"
    )
    assert peak < RSS_LIMIT, f"the server peaked at {peak / 1024**2:.0f} MB"
