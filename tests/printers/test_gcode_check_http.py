"""Uploads over real HTTP, printed by the worker on a simulator over a real pty:
a file is either refused at upload with its line number, or printed to the end.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import httpx
import pytest

from tests.conftest import wait_for
from tests.hosts import Host

if TYPE_CHECKING:
    from pathlib import Path

pytestmark = pytest.mark.slow

PRINTABLE = (
    "; Grüße aus Köln: a comment is never sent\n"
    "G28\n"
    "M117 Grüße\n"
    "G1 X10\tY10 F3000 ; Düse\n"
    "M118 Temperatur 200 °C erreicht\n"
    "M117 Schicht\x7f1\n"
    "G1 X20 Y20\n"
).encode()
REFUSED = {
    "del.gcode": (b"G28\nG1 X1\nG1 X2\x7f\n", "line 3: control byte 0x7f"),
    "umlaut.gcode": ("G28\nG1 X1 Ü\n".encode(), "line 2: 'Ü' (U+00DC)"),
    "latin1.gcode": (b"G28\nG1 X1\nG1 X\xfc\n", "line 3: a byte that is not UTF-8"),
}


def _upload(client: httpx.Client, name: str, content: bytes) -> httpx.Response:
    return client.post(
        "/printer/job/mk3",
        data={"a": "upload", "name": name, "autostart": "true"},
        files={"filename": (name, content, "application/octet-stream")},
    )


def test_uploads_are_refused_with_the_line_or_print_to_the_end(tmp_path: Path) -> None:
    host = Host(tmp_path)
    host.migrate()
    record = host.add_simulated_printer("mk3")
    key = host.add_user("op", role="operator")
    with host.running():
        client = httpx.Client(base_url=host.url, headers={"X-Api-Key": key}, timeout=30)
        for name, (content, where) in REFUSED.items():
            response = _upload(client, name, content)
            assert response.status_code == 400, response.text
            assert f"{name} {where}" in response.json()["error"], response.text
        assert client.get("/printer/job/mk3?a=list").json()["data"] == []

        response = _upload(client, "gruss.gcode", PRINTABLE)
        assert response.status_code == 200, response.text
        job_id = response.json()["data"]["id"]

        def job() -> dict:
            jobs = client.get("/printer/job/mk3?a=list").json()["data"]
            return next(j for j in jobs if j["id"] == job_id)

        wait_for(
            lambda: job()["state"] in ("completed", "failed", "aborted"),
            120,
            "the job to end",
        )
        assert job()["state"] == "completed", job()
        wait_for(lambda: "G1 X20 Y20" in record.read_text(), 10, "the record to flush")
    executed = record.read_text().splitlines()
    assert "M117 Grusse" in executed
    assert "G1 X10 Y10 F3000" in executed
    assert "M118 Temperatur 200 degC erreicht" in executed
    assert "M117 Schicht?1" in executed
