"""The seed's `/printer/` API on jobs: uploads (whole and chunked), start, pause,
delete, reprint and the queue's order, with their error paths."""

from __future__ import annotations

import pytest
from django.contrib.auth import get_user_model
from django.core.files.uploadedfile import SimpleUploadedFile

from jobs.models import Job
from printers.models import Printer, QueuedCommand
from printhost.access import issue_key
from printhost.models import AuditEntry, PrinterRole, Role
from tests.api.printer_api_helpers import GCODE, call
from tests.slices import PRUSA, to_binary


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
