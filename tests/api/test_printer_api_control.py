"""The seed's `/printer/` API on the printers: the list, commands, the response log,
the state, and connect, bed-clear and emergency actions."""

from __future__ import annotations

from datetime import timedelta

import pytest
from django.utils import timezone

from jobs.models import Job
from printers.models import Printer, QueuedCommand, ResponseLine
from printhost.models import AuditEntry
from tests.api.printer_api_helpers import GCODE, call


def test_list_shows_the_seed_fields_without_an_error_key(keys, printer) -> None:
    status, body = call("get", "/printer/list", keys("viewer"))
    assert status == 200
    assert "error" not in body  # PrusaSlicer fails on any `error` key
    assert body["data"] == [
        {
            "name": "MK3",
            "slug": "mk3",
            "online": 1,
            "active": True,
            "job": "none",
            "state": "idle",
        }
    ]


def test_list_hides_printers_a_bound_key_cannot_see(keys, make_printer) -> None:
    other = make_printer(slug="other")
    status, body = call("get", "/printer/list", keys("viewer", bound=other))
    assert [p["slug"] for p in body["data"]] == ["other"]


def test_anonymous_caller_gets_401(printer) -> None:
    status, body = call("get", "/printer/list")
    assert status == 401
    assert body["error"]


def test_info_answers_as_repetier_server(keys, printer) -> None:
    status, body = call("get", "/printer/info", keys("viewer"))
    assert status == 200
    assert body["software"] == "Repetier-Server"
    assert body["name"].startswith("Repetier")
    assert body["printers"][0]["slug"] == "mk3"


def test_send_queues_a_command_and_audits_it(keys, printer) -> None:
    status, body = call("get", "/printer/send/mk3?cmd=G28", keys())
    assert status == 200, body
    assert body["error"] == ""
    row = QueuedCommand.objects.get(pk=body["data"]["id"])
    assert row.text == "G28"
    assert AuditEntry.objects.filter(action="command", detail="G28").exists()


@pytest.mark.parametrize(
    ("path", "status", "error"),
    [
        ("/printer/send/nope?cmd=G28", 404, "Unknown printer"),
        ("/printer/send/mk3", 400, "cmd is required"),
    ],
)
def test_send_errors(keys, printer, path: str, status: int, error: str) -> None:
    got, body = call("get", path, keys())
    assert got == status
    assert error in body["error"]


def test_send_to_an_offline_printer_is_409_but_m112_passes(keys, printer) -> None:
    Printer.objects.filter(pk=printer.pk).update(state=Printer.State.OFFLINE)
    status, body = call("get", "/printer/send/mk3?cmd=G28", keys())
    assert (status, body["error"]) == (409, "Printer offline")
    status, body = call("get", "/printer/send/mk3?cmd=M112", keys())
    assert status == 200
    assert QueuedCommand.objects.get(pk=body["data"]["id"]).kind == "emergency"


def test_viewer_may_not_send(keys, printer) -> None:
    status, body = call("get", "/printer/send/mk3?cmd=G28", keys("viewer"))
    assert status == 403
    assert not QueuedCommand.objects.exists()


def test_esp_command_without_a_worker_reply_says_so(keys, printer, settings) -> None:
    settings.PRINTHOST_ESP_REPLY_SECONDS = 0.2
    status, body = call("get", "/printer/send/mk3?cmd=[ESP701]", keys())
    assert status == 504
    assert "stays queued" in body["error"]
    assert QueuedCommand.objects.get(pk=body["data"]["id"]).state == "pending"


def _log(printer: Printer, *lines: tuple[str, int]) -> None:
    for seq, (text, kind) in enumerate(lines, start=1):
        ResponseLine.objects.create(
            printer=printer, seq=seq, time=timezone.now(), text=text, kind=kind
        )


def test_response_returns_lines_after_start_without_filtered_kinds(
    keys, printer
) -> None:
    _log(printer, ("G28", 1), ("ok", 2), ("echo:busy", 4), ("Error:x", 8), ("M105", 1))
    status, body = call("get", "/printer/response/mk3?start=1&filter=3", keys("viewer"))
    assert status == 200
    data = body["data"]
    assert [(line["id"], line["text"], line["type"]) for line in data["lines"]] == [
        (3, "echo:busy", 4),
        (4, "Error:x", 8),
    ]
    assert data["lastid"] == 5
    assert data["state"]["state"] == "idle"


@pytest.mark.parametrize("query", ["start=abc", "filter=x", "filter=16", "start=-1"])
def test_response_rejects_garbage_with_400(keys, printer, query: str) -> None:
    status, body = call("get", f"/printer/response/mk3?{query}", keys("viewer"))
    assert status == 400
    assert body["error"]


def test_state_shows_job_progress_eta_and_queue(keys, printer, make_job) -> None:
    running = make_job(printer, GCODE)
    waiting = make_job(printer, GCODE)
    Job.objects.filter(pk=running.pk).update(
        state=Job.State.PRINTING,
        started_at=timezone.now() - timedelta(seconds=100),
        bytes_acked=running.size_bytes // 2,
    )
    Printer.objects.filter(pk=printer.pk).update(
        state=Printer.State.PRINTING,
        temperatures={"T0": {"current": 200.0, "target": 210.0}},
        machine_status={"state": "Run", "x": 1.0, "y": 2.0, "z": 3.0},
    )
    status, body = call("get", "/printer/state/mk3", keys("viewer"))
    assert status == 200
    data = body["data"]
    assert data["state"] == "printing"
    assert data["position"] == {"x": 1.0, "y": 2.0, "z": 3.0}
    assert data["job"]["id"] == running.pk
    assert 90 < data["job"]["eta"] < 130
    assert [j["id"] for j in data["queue"]] == [waiting.pk]
    assert data["waitstart"] is False


@pytest.mark.parametrize(
    ("path", "action"),
    [
        ("/printer/connect/mk3", "reconnect"),
        ("/printer/disconnect/mk3", "disconnect"),
    ],
)
def test_connect_and_disconnect_queue_actions(keys, printer, path, action) -> None:
    status, body = call("post", path, keys())
    assert status == 200
    assert QueuedCommand.objects.get(pk=body["data"]["id"]).text == action
    assert call("post", path, keys("viewer"))[0] == 403


def test_bedclear_only_while_waiting(keys, printer) -> None:
    key = keys()
    assert call("post", "/printer/bedclear/mk3", key)[0] == 409
    Printer.objects.filter(pk=printer.pk).update(state=Printer.State.WAITSTART)
    status, body = call("post", "/printer/bedclear/mk3", key)
    assert status == 200
    assert QueuedCommand.objects.get(pk=body["data"]["id"]).text == "bed_clear"


def test_emergency_stop_is_queued_as_an_emergency(keys, printer) -> None:
    status, body = call("post", "/printer/emergency/mk3", keys())
    assert status == 200
    assert QueuedCommand.objects.get(pk=body["data"]["id"]).kind == "emergency"
    assert AuditEntry.objects.filter(action="emergency").exists()
    assert call("post", "/printer/emergency/nope", keys())[0] == 404
