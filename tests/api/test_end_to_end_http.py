"""The `/printer/` API over real HTTP (httpx -> daphne) onto a simulated Marlin printer.

Upload a file the way PrusaSlicer does, watch it print, read the response log, answer
an [ESP701] through the worker, confirm the bed is clear, and stop the machine. Then a
resumable upload whose connection drops mid-PATCH is continued to the same SHA-256.
"""

from __future__ import annotations

import hashlib
import socket
from typing import TYPE_CHECKING

import httpx
import pytest

from printers.sample_gcode import commands_of, segments
from tests.conftest import HOST_COMMANDS, wait_for
from tests.hosts import Host

if TYPE_CHECKING:
    from pathlib import Path

pytestmark = pytest.mark.slow


def _printer(client: httpx.Client, slug: str) -> dict:
    response = client.get(f"/printer/state/{slug}")
    assert response.status_code == 200, response.text
    return response.json()["data"]


def _job(client: httpx.Client, slug: str, job_id: int) -> dict:
    jobs = client.get(f"/printer/job/{slug}?a=list").json()["data"]
    return next(j for j in jobs if j["id"] == job_id)


def _executed(record: Path) -> list[str]:
    if not record.exists():
        return []
    return [
        line
        for line in record.read_text().splitlines()
        if line and not line.startswith(HOST_COMMANDS)
    ]


def test_upload_prints_end_to_end_over_http(tmp_path: Path) -> None:
    host = Host(tmp_path)
    host.migrate()
    record = host.add_simulated_printer("mk3")
    key = host.add_user("op", role="operator")
    text = segments(300)
    with host.running():
        client = httpx.Client(base_url=host.url, headers={"X-Api-Key": key}, timeout=30)
        wait_for(
            lambda: _printer(client, "mk3")["state"] == "idle",
            60,
            "the printer to connect",
        )
        response = client.post(
            "/printer/job/mk3",
            data={"name": "e2e.gcode", "autostart": "true", "a": "upload"},
            files={
                "filename": ("e2e.gcode", text.encode(), "application/octet-stream")
            },
        )
        assert response.status_code == 200, response.text
        job_id = response.json()["data"]["id"]
        wait_for(
            lambda: _job(client, "mk3", job_id)["state"] == "completed",
            120,
            "the job to complete",
        )
        wait_for(
            lambda: _executed(record) == commands_of(text), 10, "the record to flush"
        )

        response = client.get("/printer/response/mk3?start=0&filter=0")
        lines = response.json()["data"]["lines"]
        assert response.json()["error"] == ""
        assert any(line["type"] == 1 for line in lines)
        assert response.json()["data"]["lastid"] >= lines[-1]["id"]

        reply = client.get("/printer/send/mk3", params={"cmd": "[ESP701]"})
        assert reply.status_code == 200, reply.text
        assert reply.json()["data"]["reply"]

        wait_for(
            lambda: _printer(client, "mk3")["waitstart"], 30, "waitstart after the job"
        )
        assert client.post("/printer/bedclear/mk3").status_code == 200
        wait_for(
            lambda: _printer(client, "mk3")["state"] == "idle",
            30,
            "idle after bedclear",
        )

        assert client.post("/printer/emergency/mk3").status_code == 200
        wait_for(
            lambda: (
                "M112" in record.read_text()
                or _printer(client, "mk3")["state"] == "error"
            ),
            30,
            "the emergency stop to reach the firmware",
        )


def _drop_mid_patch(port: int, path: str, key: str, at: int, body: bytes) -> None:
    """Send a PATCH's headers and the first half of its body, then hang up."""
    head = (
        f"PATCH {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Api-Key: {key}\r\n"
        f"Upload-Offset: {at}\r\nContent-Type: application/offset+octet-stream\r\n"
        f"Content-Length: {len(body)}\r\n\r\n"
    ).encode()
    with socket.create_connection(("127.0.0.1", port), timeout=10) as raw:
        raw.sendall(head + body[: len(body) // 2])


def test_resumed_upload_after_a_dropped_connection(tmp_path: Path) -> None:
    host = Host(tmp_path)
    host.migrate()
    host.shell(
        "from printers.models import Printer; Printer.objects.create("
        "name='Shelf', slug='shelf', port='/nonexistent', enabled=False)"
    )
    key = host.add_user("op", role="operator")
    data = segments(20000).encode()
    digest = hashlib.sha256(data).hexdigest()
    with host.running():
        client = httpx.Client(base_url=host.url, headers={"X-Api-Key": key}, timeout=30)
        response = client.post(
            "/printer/upload/shelf",
            params={"name": "resumed.gcode", "size": len(data), "sha256": digest},
        )
        assert response.status_code == 201, response.text
        path = f"/printer/upload/shelf/{response.json()['data']['id']}"
        third = len(data) // 3
        response = client.patch(
            path, content=data[:third], headers={"Upload-Offset": "0"}
        )
        assert response.json()["data"]["offset"] == third

        _drop_mid_patch(host.port, path, key, third, data[third : 2 * third])

        offset = int(client.head(path).headers["Upload-Offset"])
        # daphne hands a body to the app only once it is whole: the torn PATCH
        # leaves the offset where the last complete one ended.
        assert offset == third
        response = client.patch(
            path, content=data[offset:], headers={"Upload-Offset": str(offset)}
        )
        assert response.status_code == 200, response.text
        job = response.json()["data"]["job"]
        assert job["sha256"] == digest
        assert job["size"] == len(data)
