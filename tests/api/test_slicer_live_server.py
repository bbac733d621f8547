"""End to end on the real server: PrusaSlicer's OctoPrint upload prints on a printer.

daphne + worker + Marlin simulator (runhost); the requests are PrusaSlicer's (prusa3d/
PrusaSlicer src/slic3r/Utils/OctoPrint.cpp: GET api/version, then POST api/files/local
multipart `print`, `path`, `file`, header `X-Api-Key`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import httpx
import pytest

from tests.conftest import wait_for
from tests.hosts import Host

if TYPE_CHECKING:
    from pathlib import Path

GCODE = "".join(f"G1 X{i % 50} Y{i % 40} F6000\n" for i in range(40))


@pytest.mark.slow
def test_prusaslicer_octoprint_upload_with_print_runs_on_the_simulated_printer(
    tmp_path: Path,
) -> None:
    host = Host(tmp_path)
    host.migrate()
    record = host.add_simulated_printer("mk3")
    key = host.add_user("slicer", "operator", printer="mk3")
    with host.running():
        wait_for(
            lambda: host.query("SELECT state FROM printers_printer")[0][0] == "idle",
            60, "the printer to connect",
        )  # fmt: skip
        with httpx.Client(base_url=host.url, timeout=30) as http:
            version = http.get("/api/version", headers={"X-Api-Key": key})
            assert version.json()["text"].startswith("OctoPrint")
            reply = http.post(
                "/api/files/local",
                headers={"X-Api-Key": key},
                data={"print": "true", "path": ""},
                files={"file": ("cube.gcode", GCODE, "application/octet-stream")},
            )
        assert reply.status_code == 201, reply.text
        assert reply.headers["Location"].startswith(f"{host.url}/api/files/local/")
        wait_for(
            lambda: host.query("SELECT state FROM jobs_job")[0][0]
            in ("printing", "completed"),
            60, "the uploaded job to start",
        )  # fmt: skip
        wait_for(
            lambda: record.exists() and "G1 X39 Y39" in record.read_text(),
            60, "the simulator to run the job's lines",
        )  # fmt: skip
