"""[ESP700] over real HTTP to a running printhost: a path outside the printer's
storage is refused with a reason, and no byte of it reaches the printer or the
response log every viewer reads.
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

SECRET = "PROBE-7f3a-SECRET"


def _log(client: httpx.Client, slug: str) -> str:
    response = client.get(f"/printer/response/{slug}?start=0&filter=0")
    assert response.status_code == 200, response.text
    return "\n".join(line["text"] for line in response.json()["data"]["lines"])


def test_esp700_paths_outside_the_storage_are_refused_over_http(
    tmp_path: Path,
) -> None:
    host = Host(tmp_path)
    host.migrate()
    record = host.add_simulated_printer("mk3")
    key = host.add_user("op", role="operator")
    probe = tmp_path / "probe.gcode"
    probe.write_text(f"M117 {SECRET}\nG1 X1\n")
    storage = tmp_path / "jobs" / "mk3"
    storage.mkdir(parents=True)
    (storage / "link.gcode").symlink_to(probe)
    (storage / "up").symlink_to(tmp_path)
    (storage / "ok.gcode").write_text("M117 stored ok\n")
    attempts = [
        f"[ESP700]/sd/{probe}",
        f"[ESP700]stream=/sd/{probe}",
        "[ESP700]stream=/sd/../../probe.gcode",
        "[ESP700]/fs/../../probe.gcode",
        "[ESP700]/sd/link.gcode",
        "[ESP700]stream=/fs/link.gcode",
        "[ESP700]/sd/up/probe.gcode",
        "[ESP700]stream=/sd/up/probe.gcode",
    ]
    with host.running():
        client = httpx.Client(base_url=host.url, headers={"X-Api-Key": key}, timeout=30)
        wait_for(
            lambda: client.get("/printer/state/mk3").json()["data"]["state"] == "idle",
            60,
            "the printer to connect",
        )
        for command in attempts:
            response = client.get("/printer/send/mk3", params={"cmd": command})
            assert response.status_code == 200, response.text
            answer = response.json()["data"]
            assert answer["reply"].startswith("error:"), (command, answer)
            assert "storage" in answer["reply"] or "file name" in answer["reply"]
            assert SECRET not in answer["reply"]

        # A file inside the storage still runs: once it has, everything sent
        # before it has reached the firmware too.
        ok = client.get("/printer/send/mk3", params={"cmd": "[ESP700]/sd/ok.gcode"})
        assert ok.json()["data"]["reply"] == "ok", ok.text
        wait_for(
            lambda: record.exists() and "M117 stored ok" in record.read_text(),
            30,
            "the stored macro to run",
        )
        jobs = client.get("/printer/job/mk3?a=list").json()["data"]
        assert jobs == []
        assert SECRET not in _log(client, "mk3")
    assert SECRET not in record.read_text()
