"""POST /printer/prompt/<slug>: the firmware's prompt answered over real HTTP.

runhost (daphne, worker, Marlin simulator); M600 in an uploaded job parks the
printer and shows "Nozzle Parked" / "Continue"; the answer reaches it as M876 S0.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import httpx
import pytest

from tests.conftest import wait_for
from tests.hosts import Host

if TYPE_CHECKING:
    from pathlib import Path

GCODE = "G1 X1 F6000\nG1 X2\nM600\nG1 X3\nG1 X4 ; after the change\n"


@pytest.mark.slow
def test_a_prompt_answered_through_the_api_reaches_the_printer_as_m876(
    tmp_path: Path,
) -> None:
    host = Host(tmp_path)
    host.migrate()
    record = host.add_simulated_printer("mk3")
    key = host.add_user("op", "operator", printer="mk3")
    viewer = host.add_user("watcher", "viewer", printer="mk3")
    with host.running(), httpx.Client(base_url=host.url, timeout=30) as http:
        wait_for(
            lambda: host.query("SELECT state FROM printers_printer")[0][0] == "idle",
            60, "the printer to connect",
        )  # fmt: skip
        headers = {"X-Api-Key": key}
        early = http.post("/printer/prompt/mk3", headers=headers, json={"choice": 0})
        assert early.status_code == 409, early.text
        assert "not asking" in early.text
        upload = http.post(
            "/api/files/local", headers=headers, data={"print": "true", "path": ""},
            files={"file": ("change.gcode", GCODE, "application/octet-stream")},
        )  # fmt: skip
        assert upload.status_code == 201, upload.text

        def prompt() -> dict | None:
            state = http.get("/printer/state/mk3", headers=headers).json()
            return state.get("data", state).get("prompt")

        wait_for(lambda: prompt() is not None, 60, "the printer's prompt")
        assert prompt() == {
            "message": "Nozzle Parked", "choices": ["Continue"], "answerable": True,
        }  # fmt: skip
        bad = http.post("/printer/prompt/mk3", headers=headers, json={"choice": 1})
        assert bad.status_code == 422, bad.text
        assert "not one of the 1" in bad.text
        junk = http.post("/printer/prompt/mk3", headers=headers, json={"choice": "x"})
        assert junk.status_code == 422, junk.text
        denied = http.post(
            "/printer/prompt/mk3", headers={"X-Api-Key": viewer}, json={"choice": 0}
        )
        assert denied.status_code == 403, denied.text
        answer = http.post("/printer/prompt/mk3", headers=headers, json={"choice": 0})
        assert answer.status_code == 200, answer.text
        wait_for(
            lambda: host.query("SELECT state FROM jobs_job")[0][0] == "completed",
            60, "the job to complete after the answer",
        )  # fmt: skip
        assert prompt() is None
    text = record.read_text()
    assert "M876 S0" in text
    assert text.index("M600") < text.index("M876 S0")
    audit = host.query("SELECT action, detail FROM printhost_auditentry")
    assert ("prompt", "Nozzle Parked: Continue") in audit
