"""Resumable uploads: sessions, offsets, limits, checksums, dropped reads (their expiry:
tests/upkeep/test_upkeep_partial_uploads.py)."""

from __future__ import annotations

import hashlib
import json
from typing import TYPE_CHECKING

import pytest
from django.contrib.auth import get_user_model
from django.test import Client

from jobs import uploads as sessions
from jobs.models import Job, Upload
from printers.models import Printer
from printhost.access import issue_key
from printhost.models import PrinterRole, Role
from tests.conftest import rows_made

if TYPE_CHECKING:
    from collections.abc import Callable

DATA = b"".join(b"G1 X%d Y%d\n" % (i, i) for i in range(200))


@pytest.fixture
def printer(make_printer: Callable[..., Printer]) -> Printer:
    return make_printer(slug="mk3", state=Printer.State.IDLE)


@pytest.fixture
def key(printer: Printer) -> str:
    user = get_user_model().objects.create_user("op")
    PrinterRole.objects.create(user=user, role=Role.OPERATOR)
    return issue_key(user, "test")[1]


def call(method: str, path: str, key: str, **kwargs: object) -> tuple[int, dict, dict]:
    response = getattr(Client(), method)(path, HTTP_X_API_KEY=key, **kwargs)
    body = json.loads(response.content) if response.content else {}
    return response.status_code, body, dict(response.headers)


def open_session(key: str, size: int = len(DATA), **extra: str) -> str:
    query = "&".join(
        f"{k}={v}" for k, v in {"name": "big.gcode", "size": size, **extra}.items()
    )
    status, body, headers = call("post", f"/printer/upload/mk3?{query}", key)
    assert status == 201, body
    assert body["data"]["offset"] == 0
    assert headers["Upload-Offset"] == "0"
    return body["data"]["id"]


def patch(key: str, upload_id: str, at: int, data: bytes) -> tuple[int, dict, dict]:
    return call(
        "patch",
        f"/printer/upload/mk3/{upload_id}",
        key,
        data=data,
        content_type="application/offset+octet-stream",
        HTTP_UPLOAD_OFFSET=str(at),
    )


def test_patches_in_order_store_the_job_with_its_sha256(key, printer) -> None:
    upload_id = open_session(key, sha256=hashlib.sha256(DATA).hexdigest())
    status, body, headers = patch(key, upload_id, 0, DATA[:1000])
    assert (status, body["data"]["offset"], headers["Upload-Offset"]) == (
        200,
        1000,
        "1000",
    )
    status, body, _ = patch(key, upload_id, 1000, DATA[1000:])
    assert status == 200, body
    job = Job.objects.get(pk=body["data"]["job"]["id"])
    assert job.sha256 == hashlib.sha256(DATA).hexdigest()
    assert job.state == Job.State.QUEUED
    assert job.path.read_bytes() == DATA
    assert not Upload.objects.exists()


def test_offset_query_by_head_and_get(key, printer) -> None:
    upload_id = open_session(key)
    patch(key, upload_id, 0, DATA[:300])
    status, _, headers = call("head", f"/printer/upload/mk3/{upload_id}", key)
    assert (status, headers["Upload-Offset"]) == (200, "300")
    status, body, _ = call("get", f"/printer/upload/mk3/{upload_id}", key)
    assert body["data"]["offset"] == 300


def test_wrong_offset_is_409_with_the_right_one_and_writes_nothing(
    key, printer
) -> None:
    upload_id = open_session(key)
    patch(key, upload_id, 0, DATA[:300])
    status, body, headers = patch(key, upload_id, 100, DATA[100:200])
    assert status == 409
    assert body["data"]["offset"] == 300
    assert headers["Upload-Offset"] == "300"
    assert "300" in body["error"]
    assert Upload.objects.get().partial_path.read_bytes() == DATA[:300]


def test_bytes_past_the_announced_size_are_413(key, printer) -> None:
    upload_id = open_session(key, size=100)
    status, body, _ = patch(key, upload_id, 0, DATA[:150])
    assert status == 413
    assert "over the limit" in body["error"]
    assert sessions.offset_of(Upload.objects.get()) == 0


def test_size_over_the_host_limit_is_413_before_any_byte(
    key, printer, settings
) -> None:
    settings.PRINTHOST_MAX_JOB_BYTES = 1000
    status, body, _ = call("post", "/printer/upload/mk3?name=a.gcode&size=2000", key)
    assert status == 413
    assert "over the limit of 1000 bytes" in body["error"]
    assert not Upload.objects.exists()


@pytest.mark.parametrize(
    ("query", "message"),
    [
        ("size=10", "name is required"),
        ("name=a.gcode", "size is required"),
        ("name=a.gcode&size=ten", "size must be an integer"),
        ("name=a.gcode&size=10&sha256=zz", "64 hex digits"),
        ("name=a.gcode&size=10&autostart=maybe", "autostart"),
    ],
)
def test_bad_session_parameters_are_400(key, printer, query, message) -> None:
    status, body, _ = call("post", f"/printer/upload/mk3?{query}", key)
    assert status == 400
    assert message in body["error"]


def test_missing_offset_header_is_400(key, printer) -> None:
    upload_id = open_session(key)
    status, body, _ = call(
        "patch", f"/printer/upload/mk3/{upload_id}", key, data=b"G28\n"
    )
    assert status == 400
    assert "Upload-Offset" in body["error"]


def test_sha256_mismatch_is_422_and_keeps_no_job(key, printer) -> None:
    upload_id = open_session(key, sha256="0" * 64)
    with rows_made(Job) as made:
        status, body, _ = patch(key, upload_id, 0, DATA)
    assert status == 422
    assert "SHA-256" in body["error"]
    assert made == []  # never queued, not even for a moment its worker could see


def test_binary_file_is_refused_at_the_end(key, printer) -> None:
    data = b"G28\n\x00\x00\x00\xff"
    upload_id = open_session(key, size=len(data))
    status, body, _ = patch(key, upload_id, 0, data)
    assert status == 400
    assert not Job.objects.exists()


def test_unknown_session_is_404_and_other_users_sessions_are_403(key, printer) -> None:
    assert call("head", "/printer/upload/mk3/nope", key)[0] == 404
    upload_id = open_session(key)
    other = get_user_model().objects.create_user("other")
    PrinterRole.objects.create(user=other, role=Role.OPERATOR)
    other_key = issue_key(other, "test")[1]
    assert call("get", f"/printer/upload/mk3/{upload_id}", other_key)[0] == 403


def test_delete_abandons_the_session(key, printer) -> None:
    upload_id = open_session(key)
    patch(key, upload_id, 0, DATA[:10])
    partial = Upload.objects.get().partial_path
    status, _, _ = call("delete", f"/printer/upload/mk3/{upload_id}", key)
    assert status == 200
    assert not partial.exists()
    assert not Upload.objects.exists()


def test_a_read_that_fails_midway_keeps_what_arrived(printer) -> None:
    upload = sessions.open_upload(printer, "x.gcode", size=len(DATA))
    pieces = [DATA[:100], DATA[100:250]]

    def read(_: int) -> bytes:
        if pieces:
            return pieces.pop(0)
        raise OSError("connection reset")

    with pytest.raises(OSError):
        sessions.append(upload, read, offset=0)
    assert sessions.offset_of(upload) == 250
    rest = [DATA[250:], b""]
    sessions.append(upload, lambda _: rest.pop(0), offset=250)
    job = sessions.finish(upload)
    assert job.path.read_bytes() == DATA
