"""The SD card routes (`/printer/sd/<slug>...`) through Django's test client."""

from __future__ import annotations

import json

import pytest

from jobs.models import Job
from jobs.services import enqueue_job
from printers.models import Printer, QueuedCommand
from printhost.models import AuditEntry
from tests.api.printer_api_helpers import call

CARD = {
    "present": True,
    "files": [{"name": "CUBE.GCO", "size": 1234, "long_name": "cube.gcode"}],
    "listed": "2026-11-23T10:00:00+00:00",
    "message": "",
}


def post(path: str, key: str, body: object) -> tuple[int, dict]:
    return call(
        "post", path, key, data=json.dumps(body), content_type="application/json"
    )


@pytest.fixture
def listed(printer: Printer) -> Printer:
    printer.sd_card = CARD
    printer.save()
    return printer


@pytest.fixture
def stored(listed: Printer, tmp_path) -> Job:
    source = tmp_path / "bracket holder.gcode"
    source.write_text("G28\nG1 X10\n")
    return enqueue_job(listed, source, queue=False)


def test_a_viewer_reads_the_card_as_last_listed(keys, listed) -> None:
    status, body = call("get", "/printer/sd/mk3", keys("viewer"))
    assert status == 200
    assert body["data"] == {"supported": True, **CARD}


def test_a_viewer_may_not_print_copy_list_or_delete(keys, stored) -> None:
    viewer = keys("viewer")
    for path, payload in (
        ("/printer/sd/mk3/print", {"name": "CUBE.GCO"}),
        ("/printer/sd/mk3/upload", {"job": stored.pk}),
        ("/printer/sd/mk3/refresh", {}),
        ("/printer/sd/mk3/delete", {"name": "CUBE.GCO"}),
    ):
        assert post(path, viewer, payload)[0] == 403, path
    assert not Job.objects.exclude(pk=stored.pk).exists()
    assert not QueuedCommand.objects.exists()


def test_print_queues_a_job_named_and_sized_from_the_listing(keys, listed) -> None:
    status, body = post("/printer/sd/mk3/print", keys(), {"name": "cube.gco"})
    assert status == 201, body
    job = Job.objects.get(pk=body["data"]["id"])
    assert (job.kind, job.sd_name, job.name, job.size_bytes, job.state) == (
        "sd_print", "CUBE.GCO", "cube.gcode", 1234, "queued",
    )  # fmt: skip
    assert body["data"]["kind"] == "sd_print"
    assert AuditEntry.objects.filter(action="sd.print", job=job).exists()


@pytest.mark.parametrize("name", ["A B.GCO", "X;M112", "X*12", "../X.GCO", "", 7])
def test_names_a_command_line_cannot_carry_are_refused(keys, listed, name) -> None:
    status, body = post("/printer/sd/mk3/print", keys(), {"name": name})
    assert status == 422, body
    assert body["error"]
    assert not Job.objects.exists()


def test_upload_queues_a_copy_with_an_8_3_name_and_print_after(keys, stored) -> None:
    status, body = post(
        "/printer/sd/mk3/upload", keys(), {"job": stored.pk, "print": True}
    )
    assert status == 201, body
    job = Job.objects.get(pk=body["data"]["id"])
    assert (job.kind, job.sd_name, job.print_after, job.file) == (
        "sd_upload", "BRACKE~1.GCO", True, stored.file,
    )  # fmt: skip


def test_upload_refuses_names_that_are_not_8_3(keys, stored) -> None:
    status, body = post(
        "/printer/sd/mk3/upload", keys(), {"job": stored.pk, "name": "LONGNAME1.GCODE"}
    )
    assert status == 422, body
    assert "8.3" in body["error"]


def test_upload_of_another_printers_job_is_not_found(
    keys, stored, make_printer, tmp_path
) -> None:
    other = make_printer(slug="other")
    source = tmp_path / "x.gcode"
    source.write_text("G28\n")
    theirs = enqueue_job(other, source, queue=False)
    status, body = post("/printer/sd/mk3/upload", keys(), {"job": theirs.pk})
    assert status == 404, body
    assert not Job.objects.filter(kind="sd_upload").exists()


def test_a_print_from_the_card_cannot_be_copied_to_it(keys, listed) -> None:
    _, body = post("/printer/sd/mk3/print", keys(), {"name": "CUBE.GCO"})
    status, body = post("/printer/sd/mk3/upload", keys(), {"job": body["data"]["id"]})
    assert status == 409, body
    assert "no stored file" in body["error"]


def test_refresh_and_delete_are_requests_for_the_worker(keys, listed) -> None:
    status, body = post("/printer/sd/mk3/refresh", keys(), {})
    assert status == 202, body
    assert QueuedCommand.objects.get(pk=body["data"]["id"]).text == "sd_list"
    status, body = post("/printer/sd/mk3/delete", keys(), {"name": "cube.gco"})
    assert status == 202, body
    assert QueuedCommand.objects.get(pk=body["data"]["id"]).text == "sd_delete:CUBE.GCO"


def test_a_grbl_machine_has_no_card(keys, make_printer) -> None:
    make_printer(slug="cnc", firmware="grbl")
    status, body = call("get", "/printer/sd/cnc", keys("viewer"))
    assert status == 200 and body["data"]["supported"] is False
    status, body = post("/printer/sd/cnc/print", keys(), {"name": "A.GCO"})
    assert status == 409, body
    assert "GRBL" in body["error"]


def test_an_unknown_printer_is_not_found(keys) -> None:
    assert call("get", "/printer/sd/nope", keys("viewer"))[0] == 404


# -- OctoPrint's SD card endpoints ---------------------------------------------------


def test_octoprint_lists_the_card_and_reports_it_ready(keys, listed) -> None:
    status, body = call("get", "/p/mk3/api/files/sdcard", keys("viewer"))
    assert status == 200, body
    [entry] = body["files"]
    assert entry["origin"] == "sdcard"
    assert (entry["name"], entry["display"], entry["size"]) == (
        "CUBE.GCO", "cube.gcode", 1234,
    )  # fmt: skip
    assert call("get", "/p/mk3/api/printer/sd", keys("viewer"))[1] == {"ready": True}


def test_octoprint_select_and_print_from_the_card_queues_the_job(keys, listed) -> None:
    status, _ = post(
        "/p/mk3/api/files/sdcard/CUBE.GCO", keys(), {"command": "select", "print": True}
    )
    assert status == 204
    job = Job.objects.get()
    assert (job.kind, job.sd_name) == ("sd_print", "CUBE.GCO")
    status, _ = post("/p/mk3/api/files/sdcard/CUBE.GCO", keys(), {"command": "select"})
    assert status == 204
    assert Job.objects.count() == 1  # a bare select queues nothing


def test_octoprint_upload_to_the_card_stores_and_queues_the_copy(keys, listed) -> None:
    from django.core.files.uploadedfile import SimpleUploadedFile

    status, body = call(
        "post", "/p/mk3/api/files/sdcard", keys(),
        data={"file": SimpleUploadedFile("part.gcode", b"G28\nG1 X1\n"),
              "print": "true"},
    )  # fmt: skip
    assert status == 201, body
    assert body["files"]["sdcard"]["name"] == "PART.GCO"
    copy = Job.objects.get(kind="sd_upload")
    assert copy.print_after and copy.sd_name == "PART.GCO"
    assert Job.objects.get(kind="print").state == "stored"


def test_octoprint_card_refresh_queues_a_listing_and_release_is_refused(
    keys, listed
) -> None:
    assert post("/p/mk3/api/printer/sd", keys(), {"command": "refresh"})[0] == 204
    assert QueuedCommand.objects.get().text == "sd_list"
    status, body = post("/p/mk3/api/printer/sd", keys(), {"command": "release"})
    assert status == 409, body
