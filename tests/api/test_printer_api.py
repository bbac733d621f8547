"""The seed's `/printer/` API through Django's test client: success and error paths."""

from __future__ import annotations

import json
from datetime import timedelta
from typing import TYPE_CHECKING

import pytest
from django.contrib.auth import get_user_model
from django.core.files.uploadedfile import SimpleUploadedFile
from django.test import Client
from django.utils import timezone

from jobs.models import Job
from printers.models import Printer, QueuedCommand, ResponseLine
from printhost.access import issue_key
from printhost.models import AuditEntry, PrinterRole, Role
from tests.slices import PRUSA, to_binary

if TYPE_CHECKING:
    pass

GCODE = "G28\nG1 X10 Y10\nM104 S0\n"


def call(
    method: str, path: str, key: str | None = None, **kwargs: object
) -> tuple[int, dict]:
    headers = {"HTTP_X_API_KEY": key} if key else {}
    response = getattr(Client(), method)(path, **kwargs, **headers)
    body = response.content
    return response.status_code, json.loads(body) if body else {}


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


def _upload(
    key: str, text: str = GCODE, slug: str = "mk3", **fields: str
) -> tuple[int, dict]:
    data = {"a": "upload", **fields}
    data["filename"] = SimpleUploadedFile("part.gcode", text.encode())
    return call("post", f"/printer/job/{slug}", key, data=data)


def test_job_upload_queues_a_job(keys, printer) -> None:
    status, body = _upload(keys())
    assert status == 200, body
    job = Job.objects.get(pk=body["data"]["id"])
    assert job.state == Job.State.QUEUED
    assert job.path.read_text() == GCODE
    assert AuditEntry.objects.filter(action="job.upload", job=job).exists()


def test_job_upload_autostart_zero_only_stores(keys, printer) -> None:
    status, body = _upload(keys(), autostart="0")
    assert Job.objects.get(pk=body["data"]["id"]).state == Job.State.STORED


def test_job_upload_autostart_minus_one_queues_only_an_empty_queue(
    keys, printer
) -> None:
    key = keys()
    _, first = _upload(key, autostart="-1")
    _, second = _upload(key, autostart="-1")
    assert first["data"]["state"] == "queued"
    assert second["data"]["state"] == "stored"


def test_job_upload_of_a_binary_file_is_400_and_stores_nothing(keys, printer) -> None:
    status, body = _upload(keys(), text="G28\n\x00\x01\x02binary")
    assert status == 400
    # The error names the file the user sent, not the server's temporary file.
    assert body["error"].startswith("part.gcode line 2: ")
    assert "binary file" in body["error"]
    assert not Job.objects.exists()


def test_job_upload_of_a_broken_binary_gcode_is_400_and_stores_nothing(
    keys, printer, tmp_path
) -> None:
    good = to_binary(PRUSA, tmp_path / "box.bgcode").read_bytes()
    broken = good[: len(good) // 2]  # cut off, as a dropped transfer leaves it
    data = {"a": "upload", "filename": SimpleUploadedFile("box.bgcode", broken)}
    status, body = call("post", "/printer/job/mk3", keys(), data=data)
    assert status == 400
    assert body["error"].startswith("box.bgcode: cut off in block ")
    assert "truncated" in body["error"]
    assert not Job.objects.exists()
    data = {"a": "upload", "filename": SimpleUploadedFile("box.bgcode", good)}
    status, body = call("post", "/printer/job/mk3", keys(), data=data)
    assert status == 200, body
    assert Job.objects.get().size_bytes == len(good)


def test_job_upload_over_the_limit_is_413(keys, printer, settings) -> None:
    settings.PRINTHOST_MAX_JOB_BYTES = 10
    status, body = _upload(keys())
    assert status == 413
    assert "over the limit" in body["error"]


def test_job_upload_without_a_file_is_400(keys, printer) -> None:
    status, body = call("post", "/printer/job/mk3", keys(), data={"a": "upload"})
    assert status == 400
    assert "filename" in body["error"]


def test_bound_key_uploads_to_its_printer_and_is_refused_on_another(
    keys, printer, make_printer
) -> None:
    other = make_printer(slug="other", state=Printer.State.IDLE)
    key = keys(bound=other)
    status, body = _upload(key, slug="-")
    assert status == 200
    assert Job.objects.get(pk=body["data"]["id"]).printer == other
    status, body = _upload(key, slug="mk3")
    assert status == 403
    assert "bound to printer 'other'" in body["error"]
    assert not Job.objects.filter(printer=printer).exists()


def test_viewer_may_list_jobs_but_not_upload(keys, printer, make_job) -> None:
    make_job(printer, GCODE)
    viewer = keys("viewer")
    status, body = call("get", "/printer/job/mk3?a=list", viewer)
    assert status == 200
    assert len(body["data"]) == 1
    status, _ = _upload(viewer)
    assert status == 403


def test_unknown_job_action_is_400(keys, printer) -> None:
    status, body = call("get", "/printer/job/mk3?a=explode", keys())
    assert status == 400
    assert "explode" in body["error"]


def test_chunked_create_and_append_store_the_job(keys, printer) -> None:
    key = keys()
    data = GCODE.encode()
    status, body = call(
        "post", f"/printer/job/mk3?a=create&name=c.gcode&size={len(data)}", key
    )
    assert status == 200, body
    upload_id = body["data"]["id"]
    path = f"/printer/job/mk3?a=append&id={upload_id}"
    status, body = call(
        "post", path, key, data=data[:5], content_type="application/octet-stream"
    )
    assert body["data"]["complete"] is False
    assert body["data"]["offset"] == 5
    status, body = call(
        "post",
        path + "&offset=2",
        key,
        data=data[5:],
        content_type="application/octet-stream",
    )
    assert status == 409
    assert body["data"]["offset"] == 5
    status, body = call(
        "post",
        path + "&offset=5",
        key,
        data=data[5:],
        content_type="application/octet-stream",
    )
    assert status == 200, body
    job = Job.objects.get(pk=body["data"]["job"]["id"])
    assert job.state == Job.State.QUEUED
    assert job.path.read_bytes() == data


def test_chunked_upload_of_unknown_size_ends_with_finish(keys, printer) -> None:
    key = keys()
    _, body = call("post", "/printer/job/mk3?a=create&name=u.gcode&autostart=0", key)
    upload_id = body["data"]["id"]
    call(
        "post",
        f"/printer/job/mk3?a=append&id={upload_id}",
        key,
        data=GCODE.encode(),
        content_type="application/octet-stream",
    )
    status, body = call("post", f"/printer/job/mk3?a=finish&id={upload_id}", key)
    assert status == 200, body
    assert body["data"]["job"]["state"] == "stored"


def test_start_queues_a_stored_job_and_refuses_a_queued_one(keys, printer) -> None:
    key = keys()
    _, body = _upload(key, autostart="0")
    job_id = body["data"]["id"]
    status, body = call("get", f"/printer/job/mk3?a=start&id={job_id}", key)
    assert (status, body["data"]["state"]) == (200, "queued")
    status, body = call("get", f"/printer/job/mk3?a=start&id={job_id}", key)
    assert status == 409


def test_pause_resume_abort_need_a_running_job(keys, printer, make_job) -> None:
    key = keys()
    status, body = call("get", "/printer/job/mk3?a=pause", key)
    assert status == 409
    job = make_job(printer, GCODE)
    Job.objects.filter(pk=job.pk).update(state=Job.State.PRINTING)
    status, body = call("get", "/printer/job/mk3?a=pause", key)
    assert status == 200
    status, body = call("get", "/printer/job/mk3?a=resume", key)
    assert status == 409  # not paused
    status, body = call("post", "/printer/job/mk3?a=abort", key)
    assert status == 200
    actions = list(QueuedCommand.objects.values_list("text", flat=True))
    assert actions == ["pause", "abort"]
    assert AuditEntry.objects.filter(action="job.abort").exists()


def test_delete_refuses_a_running_job_and_removes_a_finished_one(
    keys, printer, make_job
) -> None:
    key = keys()
    job = make_job(printer, GCODE)
    Job.objects.filter(pk=job.pk).update(state=Job.State.PRINTING)
    status, _ = call("get", f"/printer/job/mk3?a=delete&id={job.pk}", key)
    assert status == 409
    assert job.path.exists()
    Job.objects.filter(pk=job.pk).update(state=Job.State.COMPLETED)
    status, _ = call("get", f"/printer/job/mk3?a=delete&id={job.pk}", key)
    assert status == 200
    assert not job.path.exists()
    assert not Job.objects.filter(pk=job.pk).exists()


def test_delete_and_reprint_of_unknown_or_missing_ids(keys, printer) -> None:
    key = keys()
    assert call("get", "/printer/job/mk3?a=delete&id=99", key)[0] == 404
    assert call("get", "/printer/job/mk3?a=reprint", key)[0] == 400
    assert call("get", "/printer/job/mk3?a=reprint&id=x", key)[0] == 400


def test_reprint_queues_the_same_file_again(keys, printer, make_job) -> None:
    job = make_job(printer, GCODE)
    Job.objects.filter(pk=job.pk).update(state=Job.State.COMPLETED)
    status, body = call("get", f"/printer/job/mk3?a=reprint&id={job.pk}", keys())
    assert status == 200
    again = Job.objects.get(pk=body["data"]["id"])
    assert (again.file, again.state) == (job.file, Job.State.QUEUED)


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


def test_queue_reorder_by_order_and_by_position(keys, printer, make_job) -> None:
    key = keys()
    a, b, c = (make_job(printer, GCODE) for _ in range(3))
    status, body = call(
        "post",
        "/printer/queue/mk3",
        key,
        data={"order": [c.pk, a.pk]},
        content_type="application/json",
    )
    assert status == 200, body
    assert [j["id"] for j in body["data"]] == [c.pk, a.pk, b.pk]
    order = list(Job.objects.filter(state="queued").values_list("pk", flat=True))
    assert order == [c.pk, a.pk, b.pk]
    status, body = call(
        "post",
        "/printer/queue/mk3",
        key,
        data={"id": b.pk, "position": 0},
        content_type="application/json",
    )
    assert [j["id"] for j in body["data"]] == [b.pk, c.pk, a.pk]


@pytest.mark.parametrize(
    ("payload", "status"),
    [
        ("not json", 400),
        ('{"order": "x"}', 400),
        ('{"order": [999]}', 409),
        ('{"id": 999, "position": 0}', 409),
        ("{}", 400),
    ],
)
def test_queue_reorder_errors(keys, printer, make_job, payload, status) -> None:
    make_job(printer, GCODE)
    got, body = call(
        "post", "/printer/queue/mk3", keys(), data=payload, content_type="text/plain"
    )
    assert got == status
    assert body["error"]


def test_upload_to_the_default_printer_when_the_url_names_none(printer) -> None:
    user = get_user_model().objects.create_user("solo")
    PrinterRole.objects.create(user=user, role=Role.OPERATOR, printer=printer)
    key = issue_key(user, "test")[1]
    data = {"a": "upload", "filename": SimpleUploadedFile("d.gcode", GCODE.encode())}
    status, body = call("post", "/printer/job/-", key, data=data)
    assert status == 200, body
    assert Job.objects.get(pk=body["data"]["id"]).printer == printer


def test_viewer_may_not_open_a_resumable_upload(keys, printer) -> None:
    status, body = call(
        "post", "/printer/upload/mk3?name=a.gcode&size=5", keys("viewer")
    )
    assert status == 403
    assert body["error"]


def test_listing_jobs_costs_the_same_queries_for_one_job_or_twenty(
    keys, printer, make_job, django_assert_max_num_queries
) -> None:
    key = keys()
    make_job(printer, GCODE)
    with django_assert_max_num_queries(20) as one:
        call("get", "/printer/job/mk3?a=list", key)
    for _ in range(19):
        make_job(printer, GCODE)
    with django_assert_max_num_queries(len(one.captured_queries)):
        status, body = call("get", "/printer/job/mk3?a=list", key)
    assert status == 200
    assert len(body["data"]) == 20
