"""End to end on the real server: PrusaSlicer's OctoPrint upload prints on a printer.

daphne + worker + Marlin simulator (runhost); the requests are PrusaSlicer's (prusa3d/
PrusaSlicer src/slic3r/Utils/OctoPrint.cpp: GET api/version, then POST api/files/local
multipart `print`, `path`, `file`, header `X-Api-Key`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import httpx
import pytest

from jobs.gcode import command_of
from tests.conftest import HOST_COMMANDS, wait_for
from tests.hosts import Host
from tests.slices import PRUSA, to_binary

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


def _executed(record: Path) -> list[str]:
    if not record.exists():
        return []
    lines = record.read_text().splitlines()
    return [line for line in lines if line and not line.startswith(HOST_COMMANDS)]


@pytest.mark.slow
def test_a_prusa_binary_gcode_upload_prints_as_its_plain_gcode(tmp_path: Path) -> None:
    # PrusaSlicer 2.7+ sends .bgcode to Prusa printers; the file is made from the
    # committed slice by libbgcode, PrusaSlicer's own library, with its defaults.
    binary = to_binary(PRUSA, tmp_path / "box.bgcode")
    plain = [
        text
        for text in (command_of(raw) for raw in PRUSA.read_bytes().splitlines())
        if text and not text.startswith(HOST_COMMANDS)
    ]
    host = Host(tmp_path)
    host.migrate()
    record = host.add_simulated_printer("mk4")
    key = host.add_user("slicer", "operator", printer="mk4")
    with host.running():
        wait_for(
            lambda: host.query("SELECT state FROM printers_printer")[0][0] == "idle",
            60, "the printer to connect",
        )  # fmt: skip
        with httpx.Client(base_url=host.url, timeout=30) as http:
            reply = http.post(
                "/api/files/local",
                headers={"X-Api-Key": key},
                data={"print": "true", "path": ""},
                files={
                    "file": (
                        "box.bgcode",
                        binary.read_bytes(),
                        "application/octet-stream",
                    )
                },
            )
        assert reply.status_code == 201, reply.text
        wait_for(
            lambda: host.query("SELECT state FROM jobs_job")[0][0] == "completed",
            240, "the binary job to complete",
        )  # fmt: skip
        wait_for(lambda: len(_executed(record)) >= len(plain), 10, "the last moves")
    assert _executed(record) == plain
    size, stored = host.query("SELECT size_bytes, file FROM jobs_job")[0]
    assert size == binary.stat().st_size
    assert (tmp_path / "jobs" / stored).read_bytes() == binary.read_bytes()
