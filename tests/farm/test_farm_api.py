"""The farm's API: uploads to the `farm` pseudo-printer through every upload path,
the queue with its reasons and "would go to", changes, cancelling, what a printer
has loaded, and bad input refused with a message and nothing changed."""

from __future__ import annotations

import hashlib
from typing import TYPE_CHECKING, Any

import pytest
from django.contrib.auth import get_user_model
from django.core.exceptions import ValidationError
from django.core.files.uploadedfile import SimpleUploadedFile
from django.test import Client

from jobs.analysis_task import run
from jobs.farm.dispatch import Dispatcher
from jobs.farm.models import FarmJob
from jobs.models import FileAnalysis
from printers.models import Printer
from printhost.access import issue_key
from printhost.models import AuditEntry, PrinterRole, Role
from tests.conftest import rows_made
from tests.farm.conftest import box_gcode

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

pytestmark = pytest.mark.django_db

PART = box_gcode(100, 50, 30)


@pytest.fixture
def key(db: None) -> Callable[..., str]:
    """A raw key of a fresh user with *role* on every printer (or on *printer*)."""

    def make(
        role: str = "operator", *, printer: Printer | None = None,
        bound: Printer | None = None,
    ) -> str:  # fmt: skip
        count = get_user_model().objects.count()
        user = get_user_model().objects.create_user(f"{role}{count}")
        PrinterRole.objects.create(user=user, role=Role[role.upper()], printer=printer)
        return issue_key(user, "test", printer=bound)[1]

    return make


def send(
    method: str, path: str, key: str, *, file: str | None = None, **data: Any
) -> tuple[int, dict]:
    kwargs: dict[str, Any] = {"headers": {"X-Api-Key": key}}
    if file is not None:
        kwargs["data"] = {"file": SimpleUploadedFile("part.gcode", file.encode())}
        kwargs["data"] |= data
    elif data:
        kwargs |= {"data": data, "content_type": "application/json"}
    response = getattr(Client(), method)(path, **kwargs)
    return response.status_code, response.json()


def farm_files(storage: Path) -> list[str]:
    folder = storage / "farm"
    return sorted(p.name for p in folder.iterdir()) if folder.exists() else []


def test_the_seed_upload_queues_a_farm_job_with_requirements_from_the_query(
    storage: Path, key: Callable[..., str]
) -> None:
    status, body = send(
        "post", "/printer/job/farm?a=upload&material=PETG&nozzle=0.6&tags=enclosed",
        key(), file=PART, priority="2", colour="red",
    )  # fmt: skip

    assert status == 200, body
    data = body["data"]
    assert data["state"] == "waiting" and data["priority"] == 2
    assert data["requirements"] == {
        "material": "PETG", "colour": "red", "nozzle_diameter": 0.6, "profile": "",
        "tags": ["enclosed"],
    }  # fmt: skip
    assert data["reason"] == "waiting for the file's analysis"
    assert data["sha256"] == hashlib.sha256(PART.encode()).hexdigest()
    assert len(farm_files(storage)) == 1
    assert AuditEntry.objects.filter(action="farm.upload").count() == 1


def test_octoprint_and_moonraker_uploads_on_p_farm_join_the_queue(
    key: Callable[..., str],
) -> None:
    operator = key()
    status, body = send("post", "/p/farm/api/files/local?material=PLA", operator,
                        file=PART, print="false")  # fmt: skip
    assert status == 201, body
    first = FarmJob.objects.get()
    assert body["files"]["local"]["refs"]["resource"].endswith(
        f"/printer/farm/{first.pk}"
    )
    assert first.material == "PLA"

    checksum = hashlib.sha256(PART.encode()).hexdigest()
    status, body = send("post", "/p/farm/server/files/upload", operator, file=PART,
                        checksum=checksum, tags="enclosed,hardened")  # fmt: skip
    assert status == 201 and body["print_queued"] is True, body
    assert FarmJob.objects.latest("id").tags == ["enclosed", "hardened"]

    status, body = send("get", "/p/farm/server/info", operator)
    assert status == 200 and body["result"]["klippy_state"] == "ready"
    status, body = send("get", "/p/farm/api/printer", operator)
    assert status == 404 and "the farm queue, not a printer" in body["error"]


@pytest.mark.parametrize(
    ("path", "fields", "status", "message"),
    [
        ("/printer/job/farm?a=upload&nozzle=wide", {}, 400, "nozzle must be a diameter"),
        ("/printer/job/farm?a=upload", {"priority": "urgent"}, 400,
         "priority must be a whole number"),
        ("/printer/job/farm?a=upload", {"deadline": "friday"}, 400,
         "deadline must be an ISO 8601 time"),
        # Stored, these could not be read back on PostgreSQL (before the year 1
        # or after 9999 in UTC) and every read of the queue would fail.
        ("/printer/job/farm?a=upload", {"deadline": "0001-01-01T00:00:00+14:00"},
         400, "deadline must fall in the years 2000 to 2200"),
        ("/printer/job/farm?a=upload", {"deadline": "9999-12-31T23:59:59-14:00"},
         400, "deadline must fall in the years 2000 to 2200"),
        ("/printer/job/farm?a=create&name=x.gcode", {}, 400, "the farm takes a=upload"),
        # Else the job would wait for any printer, a PLA one for a PETG part.
        ("/printer/job/farm?a=upload&materal=PETG", {}, 400,
         "unknown field 'materal': did you mean 'material'?"),
        ("/p/farm/server/files/upload", {"Material": "PETG"}, 400,
         "unknown field 'Material': did you mean 'material'?"),
        ("/p/farm/api/files/local", {"tag": "enclosed"}, 400,
         "unknown field 'tag': did you mean 'tags'?"),
        ("/p/farm/server/files/upload", {"checksum": "0" * 64}, 422, "does not match"),
    ],
)  # fmt: skip
def test_bad_farm_uploads_are_refused_and_nothing_is_stored(
    storage: Path, key: Callable[..., str], path: str, fields: dict, status: int,
    message: str,
) -> None:  # fmt: skip
    with rows_made(FarmJob, FileAnalysis, AuditEntry) as made:
        got, body = send("post", path, key(), file=PART, **fields)
    error = body.get("error")
    text = error["message"] if isinstance(error, dict) else error
    assert got == status and message in text, body
    assert made == []  # not for a moment: a dispatcher could have given it
    assert farm_files(storage) == []


def test_a_broken_file_is_refused_like_any_upload(
    storage: Path, key: Callable[..., str]
) -> None:
    status, body = send("post", "/printer/job/farm?a=upload", key(), file="; nothing\n")
    assert status == 400 and "holds no G-code command" in body["error"]
    assert farm_files(storage) == []


#: The three dialects' farm uploads.
FARM_UPLOADS = (
    "/printer/job/farm?a=upload",
    "/p/farm/api/files/local",
    "/p/farm/server/files/upload",
)
#: A multipart body Django cannot read (no boundary): a 400 once read.
NO_BOUNDARY: dict[str, Any] = {"data": b"x", "content_type": "multipart/form-data"}


def test_every_upload_checks_its_caller_before_its_body_which_if_broken_is_a_400(
    make_printer: Callable[..., Printer], key: Callable[..., str]
) -> None:
    mk3 = make_printer(slug="mk3")
    make_printer(slug="other")
    uploads = (
        "/printer/job/other?a=upload", "/printer/job/other",
        "/p/other/api/files/local", "/p/other/server/files/upload",
        "/p/other/api/files/sdcard", "/printer/model/other",
    )  # fmt: skip
    outsider, operator = key(printer=mk3), key()
    for path in uploads + FARM_UPLOADS:
        refused = Client().post(path, headers={"X-Api-Key": outsider}, **NO_BOUNDARY)
        assert refused.status_code == 403, (path, refused.content)
        broken = Client().post(path, headers={"X-Api-Key": operator}, **NO_BOUNDARY)
        assert broken.status_code == 400, (path, broken.content)
        assert b"multipart" in broken.content, (path, broken.content)


def test_only_an_operator_of_every_printer_with_an_unbound_key_may_queue(
    make_printer: Callable[..., Printer], key: Callable[..., str]
) -> None:
    mk3 = make_printer(slug="mk3")
    refusals = {
        "operator of one printer": key(printer=mk3),
        "viewer of every printer": key("viewer"),
        "bound key": key(bound=mk3),
    }
    for who, raw in refusals.items():
        status, body = send("post", "/printer/job/farm?a=upload", raw, file=PART)
        assert status == 403, who
        assert "every printer" in body["error"] or "bound" in body["error"], body
        # Refused before the body is read: one that cannot be parsed is not looked at.
        for path in FARM_UPLOADS:
            response = Client().post(path, headers={"X-Api-Key": raw}, **NO_BOUNDARY)
            assert response.status_code == 403, (who, path, response.content)
    assert not FarmJob.objects.exists()
    status, _ = send("get", "/printer/farm", key("viewer"))
    assert status == 200


def test_the_queue_lists_reasons_would_go_to_and_where_jobs_went(
    farm_printer: Callable[..., Printer],
    to_farm: Callable[..., FarmJob],
    key: Callable[..., str],
) -> None:
    farm_printer("mk3-a", material="PLA")
    farm_printer("mk3-b", material="PLA")
    given = to_farm(PART, name="given.gcode")
    Dispatcher().run_pass()
    petg = to_farm(PART, name="petg.gcode", material="PETG")
    waiting = to_farm(PART, name="next.gcode")
    FarmJob.objects.filter(pk=petg.pk).update(reason="no printer has PETG loaded")

    status, body = send("get", "/printer/farm", key("viewer"))

    assert status == 200
    jobs = {job["name"]: job for job in body["data"]["jobs"]}
    assert jobs["petg.gcode"]["would_go_to"] is None
    assert jobs["petg.gcode"]["reason"] == "no printer has PETG loaded"
    assert jobs["next.gcode"]["would_go_to"] == "mk3-b"
    assert jobs["given.gcode"]["printer"] == "mk3-a"
    assert jobs["given.gcode"]["job"]["state"] == "queued"
    assert [j["name"] for j in body["data"]["jobs"]][:2] == ["petg.gcode", "next.gcode"]
    printers = {p["slug"]: p for p in body["data"]["printers"]}
    assert printers["mk3-a"]["busy"] == "has a job queued"
    assert printers["mk3-b"]["free"] is True and printers["mk3-b"]["material"] == "PLA"
    assert waiting.state == "waiting" and given.state == "waiting"  # before the pass


def test_changes_and_cancelling_are_checked_and_refused_once_given(
    farm_printer: Callable[..., Printer],
    to_farm: Callable[..., FarmJob],
    key: Callable[..., str],
) -> None:
    operator = key()
    waiting = to_farm(box_gcode(90, 50, 30), analyse=False)
    farm_printer("mk3")
    given = to_farm(PART, name="given.gcode")
    Dispatcher().run_pass()

    status, body = send("patch", f"/printer/farm/{waiting.pk}", operator,
                        nozzle=9, priority=5)  # fmt: skip
    assert status == 400 and "between 0.05 and 5 mm" in body["error"]
    waiting.refresh_from_db()
    assert (waiting.priority, waiting.nozzle_diameter) == (0, None)

    status, body = send("patch", f"/printer/farm/{waiting.pk}", operator,
                        material="ASA", deadline="2030-01-02T03:04:05Z")  # fmt: skip
    assert status == 200 and body["data"]["requirements"]["material"] == "ASA"
    assert body["data"]["deadline"].startswith("2030-01-02T03:04:05")

    for method, path in (
        ("patch", f"/printer/farm/{given.pk}"),
        ("post", f"/printer/farm/{given.pk}/cancel"),
    ):
        status, body = send(method, path, operator, priority=1)
        assert status == 409 and "already given to mk3" in body["error"]

    status, body = send("post", f"/printer/farm/{waiting.pk}/cancel", operator)
    assert status == 200 and body["data"]["state"] == "cancelled"
    status, body = send("post", f"/printer/farm/{waiting.pk}/cancel", operator)
    assert status == 409 and "cancelled" in body["error"]
    assert send("get", "/printer/farm/999", operator)[0] == 404


def test_an_operator_sets_what_a_printer_has_loaded(
    make_printer: Callable[..., Printer], key: Callable[..., str]
) -> None:
    mk3 = make_printer(slug="mk3", material="PLA", nozzle_diameter=0.4)
    operator = key(printer=mk3)

    status, body = send("post", "/printer/loaded/mk3", operator, material="PETG",
                        colour="black", nozzle="0.6")  # fmt: skip

    assert status == 200, body
    mk3.refresh_from_db()
    assert (mk3.material, mk3.colour, mk3.nozzle_diameter) == ("PETG", "black", 0.6)
    assert mk3.loaded_by.startswith("operator") and mk3.loaded_at is not None
    for fields, message in (
        ({"nozzle": "thick"}, "nozzle must be a diameter"),
        ({"spool": "A"}, "not a loaded field: spool"),
        ({}, "send material, colour or nozzle"),
    ):
        status, body = send("post", "/printer/loaded/mk3", operator, **fields)
        assert status == 400 and message in body["error"], body
    mk3.refresh_from_db()
    assert (mk3.material, mk3.nozzle_diameter) == ("PETG", 0.6)
    status, _ = send("post", "/printer/loaded/mk3", key("viewer"), material="ABS")
    assert status == 403


def test_no_printer_may_take_the_farms_slug(db: None) -> None:
    with pytest.raises(ValidationError, match="reserved for the farm queue"):
        Printer(name="Farm", slug="farm", port="/dev/ttyUSB0").full_clean()


def test_an_analysed_upload_waits_with_the_reason_no_printer_fits(
    farm_printer: Callable[..., Printer], key: Callable[..., str]
) -> None:
    farm_printer("mk3")
    status, body = send("post", "/printer/job/farm?a=upload", key(),
                        file=box_gcode(300, 50, 30))  # fmt: skip
    farm_job = FarmJob.objects.get(pk=body["data"]["id"])
    assert run(farm_job.analysis_id, worker="test") == "done"

    Dispatcher().run_pass()

    status, body = send("get", f"/printer/farm/{farm_job.pk}", key("viewer"))
    assert body["data"]["reason"] == (
        "the part (300\u00d750\u00d729.8 mm) fits no printer's build volume"
    )
    assert body["data"]["analysis"]["bbox"] == [[10.0, 10.0, 0.2], [310.0, 60.0, 30.0]]
