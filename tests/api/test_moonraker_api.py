"""The Moonraker dialect's endpoints: job control, emergency stop, errors in its shape."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest
from django.core.files.uploadedfile import SimpleUploadedFile

from jobs.models import Job
from printers.models import Printer, QueuedCommand
from printhost.access import issue_key
from printhost.models import AuditEntry, PrinterRole, Role

if TYPE_CHECKING:
    from collections.abc import Callable


@pytest.fixture
def printer(make_printer: Callable[..., Printer]) -> Printer:
    return make_printer(slug="voron", state=Printer.State.IDLE)


@pytest.fixture
def keys(django_user_model: type, printer: Printer) -> dict[str, str]:
    found = {}
    for name, role in (("op", Role.OPERATOR), ("viewer", Role.VIEWER)):
        user = django_user_model.objects.create_user(name, password=name)
        PrinterRole.objects.create(user=user, printer=printer, role=role)
        found[name] = issue_key(user, "test")[1]
    return found


def post(client: object, url: str, key: str, **data: object) -> object:
    return client.post(url, data=data, headers={"X-Api-Key": key})  # type: ignore[attr-defined]


def test_server_info_needs_a_key(client: object, keys: dict[str, str]) -> None:
    assert client.get("/server/info").status_code == 401  # type: ignore[attr-defined]
    body = client.get("/server/info", headers={"X-Api-Key": keys["viewer"]}).json()  # type: ignore[attr-defined]
    assert body["result"]["klippy_state"] == "ready"
    assert body["result"]["api_version"] == [1, 5, 0]


def test_upload_by_viewer_is_403_in_moonraker_shape(
    client: object, keys: dict[str, str]
) -> None:
    reply = post(
        client,
        "/server/files/upload",
        keys["viewer"],
        file=SimpleUploadedFile("a.gcode", b"G28\n"),
    )
    assert reply.status_code == 403
    assert reply.json()["error"]["code"] == 403
    assert not Job.objects.exists()


def test_upload_without_file_or_to_config_root_is_400(
    client: object, keys: dict[str, str]
) -> None:
    assert (
        post(client, "/server/files/upload", keys["op"], print="true").status_code
        == 400
    )
    reply = post(
        client, "/server/files/upload", keys["op"], root="config",
        file=SimpleUploadedFile("printer.cfg", b"[printer]\n"),
    )  # fmt: skip
    assert reply.status_code == 400
    assert "gcodes" in reply.json()["error"]["message"]


def test_binary_upload_is_400_with_reason(client: object, keys: dict[str, str]) -> None:
    binary = SimpleUploadedFile("a.gcode", b"\x00\xff\x00\xfe" * 64)
    reply = post(client, "/server/files/upload", keys["op"], file=binary)
    assert reply.status_code == 400
    assert reply.json()["error"]["message"]


def test_print_start_queues_a_stored_file_by_name(
    client: object, keys: dict[str, str]
) -> None:
    stored = post(
        client,
        "/server/files/upload",
        keys["op"],
        file=SimpleUploadedFile("cube.gcode", b"G28\n"),
    )
    name = stored.json()["item"]["path"]
    assert Job.objects.get().state == Job.State.STORED
    reply = post(client, f"/printer/print/start?filename={name}", keys["op"])
    assert reply.status_code == 200 and reply.json() == {"result": "ok"}
    assert Job.objects.get().state == Job.State.QUEUED
    assert AuditEntry.objects.filter(action="job.queue").exists()


def test_print_start_of_unknown_file_is_404(
    client: object, keys: dict[str, str]
) -> None:
    reply = post(client, "/printer/print/start?filename=nope.gcode", keys["op"])
    assert reply.status_code == 404
    assert "nope.gcode" in reply.json()["error"]["message"]


def test_pause_resume_cancel_act_on_the_running_job(
    client: object, keys: dict[str, str], printer: Printer, make_job: Callable[..., Job]
) -> None:
    assert post(client, "/printer/print/pause", keys["op"]).status_code == 409
    job = make_job(printer, "G28\n")
    Job.objects.filter(pk=job.pk).update(state=Job.State.PRINTING)
    assert post(client, "/printer/print/resume", keys["op"]).status_code == 409
    assert post(client, "/printer/print/pause", keys["op"]).json() == {"result": "ok"}
    Job.objects.filter(pk=job.pk).update(state=Job.State.PAUSED)
    assert post(client, "/printer/print/resume", keys["op"]).status_code == 200
    assert post(client, "/printer/print/cancel", keys["op"]).status_code == 200
    assert list(QueuedCommand.objects.values_list("text", flat=True)) == [
        "pause",
        "resume",
        "abort",
    ]
    assert post(client, "/printer/print/cancel", keys["viewer"]).status_code == 403


def test_emergency_stop_skips_the_queue(client: object, keys: dict[str, str]) -> None:
    reply = post(client, "/p/voron/printer/emergency_stop", keys["op"])
    assert reply.json() == {"result": "ok"}
    command = QueuedCommand.objects.get()
    assert command.kind == QueuedCommand.Kind.EMERGENCY
    assert AuditEntry.objects.filter(action="emergency_stop").exists()
