"""The OctoPrint dialect's endpoints: answers, printer choice, and every error path."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import pytest
from django.core.files.uploadedfile import SimpleUploadedFile

from jobs.models import Job
from printers.models import Printer, QueuedCommand
from printhost.access import issue_key
from printhost.models import AuditEntry, PrinterRole, Role, UserProfile

if TYPE_CHECKING:
    from collections.abc import Callable

GCODE = b"G28\nG1 X1\n"


@pytest.fixture
def printer(make_printer: Callable[..., Printer]) -> Printer:
    return make_printer(
        slug="mk4",
        state=Printer.State.IDLE,
        temperatures={
            "T0": {"current": 200.5, "target": 210},
            "B": {"current": 60, "target": 60},
        },
    )


@pytest.fixture
def users(django_user_model: type, printer: Printer) -> dict[str, str]:
    """Keys of an operator, a viewer, and an operator whose key is bound elsewhere."""
    keys = {}
    for name, role in (("op", Role.OPERATOR), ("viewer", Role.VIEWER)):
        user = django_user_model.objects.create_user(name, password=name)
        PrinterRole.objects.create(user=user, printer=printer, role=role)
        keys[name] = issue_key(user, "test")[1]
    other = Printer.objects.create(name="Other", slug="other", port="/nonexistent")
    PrinterRole.objects.create(
        user=django_user_model.objects.get(username="op"),
        printer=other,
        role=Role.OPERATOR,
    )
    keys["bound_other"] = issue_key(
        django_user_model.objects.get(username="op"), "other", printer=other
    )[1]
    UserProfile.objects.create(
        user=django_user_model.objects.get(username="op"), default_printer=printer
    )
    return keys


def post_json(client: object, url: str, body: object, key: str) -> object:
    return client.post(  # type: ignore[attr-defined]
        url, data=json.dumps(body), content_type="application/json",
        headers={"X-Api-Key": key},
    )  # fmt: skip


def upload(
    client: object, key: str, url: str = "/api/files/local", **data: object
) -> object:
    data.setdefault("file", SimpleUploadedFile("a.gcode", GCODE))
    return client.post(url, data=data, headers={"X-Api-Key": key})  # type: ignore[attr-defined]


def test_version_is_anonymous_and_says_octoprint(client: object, db: None) -> None:
    reply = client.get("/api/version")  # type: ignore[attr-defined]
    assert reply.status_code == 200
    body = reply.json()
    assert body["api"] == "0.1" and body["text"].startswith("OctoPrint 1.")


@pytest.mark.parametrize(
    "url",
    ["/api/server", "/api/printer", "/api/job", "/api/settings", "/api/currentuser"],
)
def test_endpoints_refuse_anonymous_callers(client: object, db: None, url: str) -> None:
    assert client.get(url).status_code == 401  # type: ignore[attr-defined]


def test_a_wrong_key_is_401(client: object, users: dict[str, str]) -> None:
    reply = client.get("/api/printer", headers={"X-Api-Key": "ph_nonsense0000000000"})  # type: ignore[attr-defined]
    assert reply.status_code == 401


@pytest.mark.parametrize("how", ["bearer", "query"])
def test_bearer_and_query_keys_work(
    client: object, users: dict[str, str], how: str
) -> None:
    key = users["op"]
    if how == "bearer":
        reply = client.get("/api/server", headers={"Authorization": f"Bearer {key}"})  # type: ignore[attr-defined]
    else:
        reply = client.get(f"/api/server?apikey={key}")  # type: ignore[attr-defined]
    assert reply.status_code == 200
    assert reply.json()["version"]


def test_printer_reports_temperatures_and_flags(
    client: object, users: dict[str, str]
) -> None:
    body = client.get("/api/printer", headers={"X-Api-Key": users["viewer"]}).json()  # type: ignore[attr-defined]
    assert body["temperature"]["tool0"] == {"actual": 200.5, "target": 210, "offset": 0}
    assert body["temperature"]["bed"]["actual"] == 60
    assert body["state"]["text"] == "Operational"
    assert body["state"]["flags"]["ready"] is True
    assert body["state"]["flags"]["printing"] is False


def test_printer_offline_is_409(
    client: object, users: dict[str, str], printer: Printer
) -> None:
    Printer.objects.filter(pk=printer.pk).update(state=Printer.State.OFFLINE)
    assert (
        client.get("/api/printer", headers={"X-Api-Key": users["op"]}).status_code
        == 409
    )  # type: ignore[attr-defined]


def test_viewer_cannot_upload_or_send_commands(
    client: object, users: dict[str, str]
) -> None:
    assert upload(client, users["viewer"]).status_code == 403
    reply = post_json(
        client, "/api/printer/command", {"commands": ["G28"]}, users["viewer"]
    )
    assert reply.status_code == 403
    assert not Job.objects.exists() and not QueuedCommand.objects.exists()


def test_key_bound_to_another_printer_is_403_on_its_prefix(
    client: object, users: dict[str, str]
) -> None:
    reply = upload(client, users["bound_other"], url="/p/mk4/api/files/local")
    assert reply.status_code == 403
    assert "bound" in reply.json()["error"]


def test_unknown_printer_prefix_is_404(client: object, users: dict[str, str]) -> None:
    assert upload(client, users["op"], url="/p/nope/api/files/local").status_code == 404


def test_upload_without_file_part_is_400(client: object, users: dict[str, str]) -> None:
    reply = client.post(
        "/api/files/local", data={"print": "true"}, headers={"X-Api-Key": users["op"]}
    )  # type: ignore[attr-defined]
    assert reply.status_code == 400
    assert "file" in reply.json()["error"]


def test_binary_upload_is_refused_with_a_reason(
    client: object, users: dict[str, str]
) -> None:
    binary = SimpleUploadedFile("model.gcode", b"\x00\x01\x02PK\x03\x04" * 100)
    reply = upload(client, users["op"], file=binary, print="true")
    assert reply.status_code in (400, 415)
    assert reply.json()["error"].startswith("model.gcode line 1: ")
    assert not Job.objects.exists()


def test_no_printer_to_choose_is_409_with_how_to_choose(
    client: object, django_user_model: type, printer: Printer
) -> None:
    user = django_user_model.objects.create_user("many", password="many")
    PrinterRole.objects.create(user=user, printer=None, role=Role.OPERATOR)
    Printer.objects.create(name="Second", slug="second", port="/nonexistent")
    reply = upload(client, issue_key(user, "x")[1])
    assert reply.status_code == 409
    assert "/p/<slug>/" in reply.json()["error"]


def test_upload_is_audited(client: object, users: dict[str, str]) -> None:
    assert upload(client, users["op"], print="true").status_code == 201
    assert AuditEntry.objects.filter(action="job.upload", printer__slug="mk4").exists()


def test_select_unknown_file_is_404(client: object, users: dict[str, str]) -> None:
    reply = post_json(
        client,
        "/api/files/local/missing.gcode",
        {"command": "select", "print": True},
        users["op"],
    )
    assert reply.status_code == 404


def test_printer_command_queues_the_commands(
    client: object, users: dict[str, str]
) -> None:
    reply = post_json(
        client, "/api/printer/command", {"commands": ["G28", "M105"]}, users["op"]
    )
    assert reply.status_code == 204
    assert QueuedCommand.objects.get().text == "G28\nM105"
    single = post_json(client, "/api/printer/command", {"command": "M114"}, users["op"])
    assert single.status_code == 204
    assert AuditEntry.objects.filter(action="command").count() == 2


def test_printer_command_without_commands_is_400(
    client: object, users: dict[str, str]
) -> None:
    assert (
        post_json(
            client, "/api/printer/command", {"commands": []}, users["op"]
        ).status_code
        == 400
    )
    bad = client.post(  # type: ignore[attr-defined]
        "/api/printer/command", data="{not json", content_type="application/json",
        headers={"X-Api-Key": users["op"]},
    )  # fmt: skip
    assert bad.status_code == 400


def test_job_commands_act_on_the_running_job_or_409(
    client: object,
    users: dict[str, str],
    printer: Printer,
    make_job: Callable[..., Job],
) -> None:
    key = users["op"]
    assert post_json(client, "/api/job", {"command": "cancel"}, key).status_code == 409
    assert post_json(client, "/api/job", {"command": "start"}, key).status_code == 409
    job = make_job(printer, "G28\n")
    Job.objects.filter(pk=job.pk).update(state=Job.State.PRINTING, bytes_acked=2)
    assert post_json(client, "/api/job", {"command": "start"}, key).status_code == 409
    pause = post_json(client, "/api/job", {"command": "pause", "action": "pause"}, key)
    assert pause.status_code == 204
    assert (
        post_json(
            client, "/api/job", {"command": "pause", "action": "resume"}, key
        ).status_code
        == 409
    )
    assert post_json(client, "/api/job", {"command": "cancel"}, key).status_code == 204
    assert list(QueuedCommand.objects.values_list("text", flat=True)) == [
        "pause",
        "abort",
    ]
    assert post_json(client, "/api/job", {"command": "dance"}, key).status_code == 400
    body = client.get("/api/job", headers={"X-Api-Key": key}).json()  # type: ignore[attr-defined]
    assert body["job"]["file"]["name"] == "job.gcode"
    assert body["progress"]["completion"] == pytest.approx(50.0)


def test_start_queues_the_selected_file(client: object, users: dict[str, str]) -> None:
    assert upload(client, users["op"], select="true").status_code == 201
    assert Job.objects.get().state == Job.State.STORED
    assert (
        post_json(client, "/api/job", {"command": "start"}, users["op"]).status_code
        == 204
    )
    assert Job.objects.get().state == Job.State.QUEUED


def test_connection_commands_become_worker_actions(
    client: object, users: dict[str, str]
) -> None:
    assert (
        post_json(
            client, "/api/connection", {"command": "disconnect"}, users["op"]
        ).status_code
        == 204
    )
    assert (
        post_json(
            client, "/api/connection", {"command": "connect"}, users["op"]
        ).status_code
        == 204
    )
    assert list(QueuedCommand.objects.values_list("text", flat=True)) == [
        "disconnect",
        "reconnect",
    ]
    assert (
        post_json(
            client, "/api/connection", {"command": "jump"}, users["op"]
        ).status_code
        == 400
    )


def test_login_with_password_opens_a_session(
    client: object, users: dict[str, str]
) -> None:
    reply = client.post(  # type: ignore[attr-defined]
        "/api/login",
        data=json.dumps({"user": "op", "pass": "op"}),
        content_type="application/json",
    )
    assert reply.status_code == 200
    assert reply.json()["name"] == "op" and reply.json()["session"]
    assert client.get("/api/currentuser").json()["name"] == "op"  # type: ignore[attr-defined]
    wrong = client.post(  # type: ignore[attr-defined]
        "/api/login",
        data=json.dumps({"user": "op", "pass": "no"}),
        content_type="application/json",
    )
    assert wrong.status_code == 401


def test_passive_login_without_credentials_is_401(client: object, db: None) -> None:
    reply = client.post(
        "/api/login",
        data=json.dumps({"passive": True}),
        content_type="application/json",
    )  # type: ignore[attr-defined]
    assert reply.status_code == 401


def test_current_user_permissions_follow_the_role(
    client: object, users: dict[str, str]
) -> None:
    viewer = client.get(
        "/api/currentuser", headers={"X-Api-Key": users["viewer"]}
    ).json()  # type: ignore[attr-defined]
    operator = client.get("/api/currentuser", headers={"X-Api-Key": users["op"]}).json()  # type: ignore[attr-defined]
    assert "STATUS" in viewer["permissions"] and "PRINT" not in viewer["permissions"]
    assert "PRINT" in operator["permissions"]


def test_printer_profiles_name_the_printer(
    client: object, users: dict[str, str]
) -> None:
    body = client.get("/api/printerprofiles", headers={"X-Api-Key": users["op"]}).json()  # type: ignore[attr-defined]
    assert body["profiles"]["_default"]["name"] == "Test printer"
