"""Cura's OctoPrint Connection plugin, replayed: app-key pairing, polling, upload, print.

Requests as in fieldOfView/Cura-OctoPrintPlugin: DiscoverOctoPrintAction.py (GET
`plugin/appkeys/probe` wants 204; POST `plugin/appkeys/request` with
`Content-Type: application/json` and `{"app": "Cura"}` wants 201 and reads
`app_token`, `auth_dialog` and the `Location` header it then polls: 202 pending,
200 `{"api_key"}`, 404 denied; then GET `api/settings` with `X-Api-Key`), and
OctoPrintOutputDevice.py (polls `api/printer`, `api/job`, POSTs `api/login`
`{"passive": true}`; uploads multipart `path`, `file` (application/octet-stream),
`select`/`print` = "true" to `api/files/local`, splits the reply's `Location` at
"api/" and, when printing is not handled in the upload, POSTs
`{"command": "select", "print": true}` to that end point).
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import pytest
from django.core.files.uploadedfile import SimpleUploadedFile
from django.test import Client

from jobs.models import Job
from printers.models import Printer
from printhost.models import AuditEntry, PrinterRole, Role

if TYPE_CHECKING:
    from collections.abc import Callable

GCODE = b";FLAVOR:Marlin\n;Generated with Cura_SteamEngine 5.7.0\nG28\nG1 X5 Y5\n"


@pytest.fixture
def printer(make_printer: Callable[..., Printer]) -> Printer:
    return make_printer(slug="ender", state=Printer.State.IDLE)


@pytest.fixture
def approver(django_user_model: type, printer: Printer) -> Client:
    """A logged-in operator's browser session (the UI's approve button)."""
    user = django_user_model.objects.create_user("ada", password="ada")
    PrinterRole.objects.create(user=user, printer=printer, role=Role.OPERATOR)
    browser = Client(enforce_csrf_checks=True)
    browser.force_login(user)
    return browser


def pair(cura: Client, approver: Client, prefix: str = "") -> str:
    """The whole pairing dance; returns the key Cura stores."""
    assert cura.get(f"{prefix}/plugin/appkeys/probe").status_code == 204
    asked = cura.post(
        f"{prefix}/plugin/appkeys/request",
        data=json.dumps({"app": "Cura"}),
        content_type="application/json",
    )
    assert asked.status_code == 201, asked.content
    assert asked.json()["app_token"] and asked.json()["auth_dialog"]
    poll_url = asked["Location"]
    assert poll_url.startswith(f"http://testserver{prefix}/plugin/appkeys/request/")
    assert cura.get(poll_url).status_code == 202

    pending = approver.get("/api/appkeys/pending").json()["data"]
    assert [p["app"] for p in pending] == ["Cura"]
    approver.get("/admin/login/")  # any page that sets the CSRF cookie
    token = approver.cookies["csrftoken"].value
    decided = approver.post(
        f"/plugin/appkeys/decision/{pending[0]['user_token']}",
        data=json.dumps({"decision": True}),
        content_type="application/json",
        headers={"X-CSRFToken": token},
    )
    assert decided.status_code == 204, decided.content

    granted = cura.get(poll_url)
    assert granted.status_code == 200
    key = granted.json()["api_key"]
    assert cura.get(poll_url).status_code == 404  # handed over once only
    return key


def cura_polls(cura: Client, key: str) -> None:
    """What Cura asks right after connecting and every few seconds."""
    auth = {"X-Api-Key": key}
    settings = cura.get("/api/settings", headers=auth)
    assert settings.status_code == 200
    assert settings.json()["feature"]["sdSupport"] is False
    login = cura.post(
        "/api/login",
        data=json.dumps({"passive": True}),
        content_type="application/json",
        headers=auth,
    )
    assert login.status_code == 200
    assert login.json()["name"] == "ada"
    printer = cura.get("/api/printer", headers=auth)
    assert printer.status_code == 200
    assert printer.json()["state"]["flags"]["operational"] is True
    assert cura.get("/api/job", headers=auth).status_code == 200


def cura_upload(cura: Client, key: str, *, select_and_print: bool) -> object:
    data: dict[str, object] = {
        "path": "",
        "file": SimpleUploadedFile("CE3_cube.gcode", GCODE, "application/octet-stream"),
    }
    if select_and_print:
        data.update(select="true", print="true")
    return cura.post("/api/files/local", data=data, headers={"X-Api-Key": key})


def test_cura_pairs_then_uploads_with_select_and_print_and_the_job_is_queued(
    approver: Client, printer: Printer
) -> None:
    cura = Client()
    key = pair(cura, approver)
    cura_polls(cura, key)
    reply = cura_upload(cura, key, select_and_print=True)
    assert reply.status_code == 201, reply.content
    end_point = reply["Location"].split("api/", 1)[1]
    assert end_point.startswith("files/local/")
    job = Job.objects.get(printer=printer)
    assert job.state == Job.State.QUEUED
    # Asking again for the same file (Cura's delayed path) does not queue it twice.
    again = cura.post(
        f"/api/{end_point}",
        data=json.dumps({"command": "select", "print": True}),
        content_type="application/json",
        headers={"X-Api-Key": key},
    )
    assert again.status_code == 204
    assert Job.objects.filter(printer=printer).count() == 1
    assert AuditEntry.objects.filter(action="appkey.grant").exists()


def test_cura_uploads_then_selects_and_prints_through_the_location(
    approver: Client, printer: Printer
) -> None:
    cura = Client()
    key = pair(cura, approver)
    reply = cura_upload(cura, key, select_and_print=False)
    assert reply.status_code == 201, reply.content
    assert Job.objects.get(printer=printer).state == Job.State.STORED
    end_point = reply["Location"].split("api/", 1)[1]
    started = cura.post(
        f"/api/{end_point}",
        data=json.dumps({"command": "select", "print": True}),
        content_type="application/json",
        headers={"X-Api-Key": key},
    )
    assert started.status_code == 204, started.content
    assert Job.objects.get(printer=printer).state == Job.State.QUEUED


def test_cura_pairing_denied_gives_404_and_no_key(
    approver: Client, printer: Printer
) -> None:
    cura = Client()
    asked = cura.post(
        "/plugin/appkeys/request",
        data=json.dumps({"app": "Cura"}),
        content_type="application/json",
    )
    pending = approver.get("/api/appkeys/pending").json()["data"]
    approver.get("/admin/login/")
    denied = approver.post(
        f"/plugin/appkeys/decision/{pending[0]['user_token']}",
        data=json.dumps({"decision": False}),
        content_type="application/json",
        headers={"X-CSRFToken": approver.cookies["csrftoken"].value},
    )
    assert denied.status_code == 204
    assert cura.get(asked["Location"]).status_code == 404


def test_pairing_through_a_printer_url_binds_the_key_to_that_printer(
    printer: Printer, approver: Client, make_printer: Callable[..., Printer]
) -> None:
    from printhost.access import find_key

    make_printer(slug="other", state=Printer.State.IDLE)
    key = pair(Client(), approver, prefix="/p/ender")
    assert find_key(key).printer == printer
    cura = Client(headers={"X-Api-Key": key})
    assert cura.get("/p/ender/api/printer").status_code == 200
    assert cura.get("/p/other/api/printer").status_code == 403
