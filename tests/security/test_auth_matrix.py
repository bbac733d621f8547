"""Every endpoint x every kind of caller gets the expected status.

Callers: anonymous, a wrong key, a viewer / an operator of printer `p`, an admin of
every printer, and an operator of every printer whose key is bound to printer `q`.
"Allowed" means the request got past authentication and permissions: any status but
401/403 and no 5xx (a 404 for a file that does not exist is fine).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest
from django.core.files.uploadedfile import SimpleUploadedFile
from django.test import Client

from printers.models import Printer
from printhost.access import issue_key
from printhost.models import ApiKey, PrinterRole, Role

PUBLIC, VIEWER, OPERATOR, ADMIN = 0, Role.VIEWER, Role.OPERATOR, Role.ADMIN


@dataclass(frozen=True)
class Endpoint:
    method: str
    path: str
    role: int
    scoped: bool  # acts on printer `p` (a key bound to `q` must be refused)
    body: str = ""  # "json:{...}", "file" (multipart G-code), "raw"

    def __str__(self) -> str:
        return f"{self.method} {self.path}"


def ep(
    method: str, path: str, role: int, *, scoped: bool = True, body: str = ""
) -> Endpoint:
    return Endpoint(method, path, role, scoped, body)


ENDPOINTS = [
    # OctoPrint dialect (slicers); /p/p/ names the printer.
    ep("GET", "/api/version", PUBLIC, scoped=False),
    # A passive login reports the caller's session or key, so it needs one.
    ep("POST", "/api/login", VIEWER, scoped=False, body='json:{"passive": true}'),
    ep("GET", "/api/server", VIEWER, scoped=False),
    ep("GET", "/api/currentuser", VIEWER, scoped=False),
    ep("GET", "/api/settings", VIEWER, scoped=False),
    ep("GET", "/p/p/api/printerprofiles", VIEWER),
    ep("GET", "/p/p/api/connection", VIEWER),
    ep("POST", "/p/p/api/connection", OPERATOR, body='json:{"command": "connect"}'),
    ep("GET", "/p/p/api/printer", VIEWER),
    ep(
        "POST", "/p/p/api/printer/command", OPERATOR, body='json:{"commands": ["M105"]}'
    ),
    ep("POST", "/p/p/api/files/local", OPERATOR, body="file"),
    ep("GET", "/p/p/api/files/local/none.gcode", VIEWER),
    ep(
        "POST",
        "/p/p/api/files/local/none.gcode",
        OPERATOR,
        body='json:{"command": "select"}',
    ),
    ep("GET", "/p/p/api/job", VIEWER),
    ep("POST", "/p/p/api/job", OPERATOR, body='json:{"command": "cancel"}'),
    # Moonraker dialect.
    ep("GET", "/p/p/server/info", VIEWER),
    ep("POST", "/p/p/server/files/upload", OPERATOR, body="file"),
    ep("POST", "/p/p/printer/print/start?filename=none.gcode", OPERATOR),
    ep("POST", "/p/p/printer/print/pause", OPERATOR),
    ep("POST", "/p/p/printer/print/resume", OPERATOR),
    ep("POST", "/p/p/printer/print/cancel", OPERATOR),
    ep("POST", "/p/p/printer/emergency_stop", OPERATOR),
    # App-key pairing (Cura) and the user's keys.
    ep("GET", "/plugin/appkeys/probe", PUBLIC, scoped=False),
    ep(
        "POST",
        "/plugin/appkeys/request",
        PUBLIC,
        scoped=False,
        body='json:{"app": "Cura"}',
    ),
    ep("GET", "/plugin/appkeys/request/no-such-token", PUBLIC, scoped=False),
    # Everyone sees the requests that name them; operators see all.
    ep("GET", "/api/appkeys/pending", VIEWER, scoped=False),
    ep("POST", "/plugin/appkeys/decision/no-such-token", VIEWER, scoped=False),
    ep("GET", "/api/keys", VIEWER, scoped=False),
    # A key bound to one printer cannot mint a key for every printer.
    ep("POST", "/api/keys", VIEWER, body='json:{"name": "more"}'),
    ep("DELETE", "/api/keys/999999", VIEWER, scoped=False),
    # The seed's /printer/ API and the host extras.
    ep("GET", "/printer/list", VIEWER, scoped=False),
    ep("GET", "/printer/info", VIEWER, scoped=False),
    ep("GET", "/printer/send/p?cmd=M105", OPERATOR),
    ep("POST", "/printer/send/p?cmd=M105", OPERATOR),
    ep("GET", "/printer/response/p?start=0", VIEWER),
    ep("GET", "/printer/job/p?a=list", VIEWER),
    ep("GET", "/printer/job/p?a=pause", OPERATOR),
    ep("POST", "/printer/job/p?a=upload", OPERATOR, body="file"),
    ep("GET", "/printer/state/p", VIEWER),
    ep("GET", "/printer/temperatures/p", VIEWER),
    ep("POST", "/printer/connect/p", OPERATOR),
    ep("POST", "/printer/disconnect/p", OPERATOR),
    ep("POST", "/printer/bedclear/p", OPERATOR),
    ep("POST", "/printer/emergency/p", OPERATOR),
    ep("POST", "/printer/queue/p", OPERATOR, body='json:{"order": []}'),
    ep("POST", "/printer/model/p", OPERATOR, body="file"),
    ep("GET", "/printer/api/p?a=listModelGroups", VIEWER),
    ep("POST", "/printer/api/p?a=listModelGroups", VIEWER),
    ep(
        "POST",
        "/printer/upload/p",
        OPERATOR,
        body='json:{"name": "a.gcode", "size": 5}',
    ),
    ep("GET", "/printer/upload/p/0123456789abcdef0123456789abcdef", OPERATOR),
    ep("HEAD", "/printer/upload/p/0123456789abcdef0123456789abcdef", OPERATOR),
    ep(
        "PATCH",
        "/printer/upload/p/0123456789abcdef0123456789abcdef",
        OPERATOR,
        body="raw",
    ),
    ep("DELETE", "/printer/upload/p/0123456789abcdef0123456789abcdef", OPERATOR),
    # The admin role.
    ep("GET", "/printer/config/p", ADMIN),
    ep("PATCH", "/printer/config/p", ADMIN, body='json:{"auto_start": true}'),
    ep("GET", "/api/users", ADMIN, scoped=False),
    ep(
        "POST",
        "/api/users/viewer/role",
        ADMIN,
        scoped=False,
        body='json:{"role": "viewer"}',
    ),
]

CALLERS = ["anonymous", "wrong key", "viewer", "operator", "admin", "bound to q"]


def expected(caller: str, endpoint: Endpoint) -> str:
    if endpoint.role == PUBLIC:
        return "allowed"
    if caller in ("anonymous", "wrong key"):
        return "401"
    if caller == "bound to q" and endpoint.scoped:
        return "403"
    held = {
        "viewer": VIEWER,
        "operator": OPERATOR,
        "admin": ADMIN,
        "bound to q": OPERATOR,
    }
    return "allowed" if held[caller] >= endpoint.role else "403"


@pytest.fixture
def keys(db: None, storage: Path, django_user_model: type) -> dict[str, str]:
    p = Printer.objects.create(name="P", slug="p", port="/dev/null")
    q = Printer.objects.create(name="Q", slug="q", port="/dev/null")
    made = {}
    for name, role, printer, bound in (
        ("viewer", Role.VIEWER, p, None),
        ("operator", Role.OPERATOR, p, None),
        ("admin", Role.ADMIN, None, None),
        ("bound", Role.OPERATOR, None, q),
    ):
        user = django_user_model.objects.create_user(name, password=name)
        PrinterRole.objects.create(user=user, printer=printer, role=role)
        made[name] = issue_key(user, "matrix", printer=bound)[1]
    made["bound to q"] = made.pop("bound")
    made["wrong key"] = "ph_" + "x" * 42
    return made


def call(client: Client, endpoint: Endpoint, key: str | None) -> int:
    headers = {"X-Api-Key": key} if key else {}
    kwargs: dict = {"headers": headers}
    if endpoint.body.startswith("json:"):
        kwargs |= {"data": endpoint.body[5:], "content_type": "application/json"}
    elif endpoint.body == "file":
        gcode = SimpleUploadedFile("cube.gcode", b"G28\nG1 X1\n")
        kwargs["data"] = {"file": gcode, "filename": gcode, "print": "false"}
    elif endpoint.body == "raw":
        kwargs |= {"data": b"G28\n", "content_type": "application/offset+octet-stream"}
        headers["Upload-Offset"] = "0"
    method = getattr(client, endpoint.method.lower())
    return method(endpoint.path, **kwargs).status_code


@pytest.mark.parametrize("endpoint", ENDPOINTS, ids=str)
def test_every_endpoint_answers_every_caller_as_expected(
    endpoint: Endpoint, keys: dict[str, str]
):
    wrong = []
    for caller in CALLERS:
        status = call(Client(), endpoint, keys.get(caller))
        want = expected(caller, endpoint)
        got = "allowed" if status not in (401, 403) and status < 500 else str(status)
        if got != want:
            wrong.append(f"{caller}: {status}, expected {want}")
    assert not wrong, f"{endpoint}: " + "; ".join(wrong)


def test_every_api_operation_is_in_the_matrix():
    from printhost.api import api

    schema = api.get_openapi_schema()
    covered = {(e.method, e.path.split("?")[0]) for e in ENDPOINTS}
    templates = [
        (method.upper(), path)
        for path, operations in schema["paths"].items()
        for method in operations
        if not path.startswith("/p/{slug}/")  # the same views as the paths without it
    ]

    def matches(method: str, template: str) -> bool:
        import re

        pattern = "^" + re.sub(r"\{[^}]+\}", "[^/]+(/.*)?", template) + "$"
        return any(
            m == method
            and (re.match(pattern, p) or re.match(pattern, p.removeprefix("/p/p")))
            for m, p in covered
        )

    missing = [f"{m} {t}" for m, t in templates if not matches(m, t)]
    assert not missing, "add these to ENDPOINTS: " + ", ".join(missing)


def test_api_keys_are_not_stored_in_clear(keys: dict[str, str]):
    stored = list(ApiKey.objects.values_list("prefix", "key_hash", "name"))
    for raw in keys.values():
        for row in stored:
            assert raw not in " ".join(row)
    assert all(len(key_hash) == 64 for _, key_hash, _ in stored)


# Websockets: watching needs the viewer role on the printer, commands the operator's.
WS_EXPECTED = {
    # caller: (watch /ws/printers/p/, watch /ws/printers/, send a command on p)
    "anonymous": (4401, 4401, None),
    "wrong key": (4401, 4401, None),
    "viewer": ("hello", "hello", "error"),
    "operator": ("hello", "hello", "queued"),
    "admin": ("hello", "hello", "queued"),
    "bound to q": (4403, "hello", None),
}


async def _ws_outcome(path: str, key: str | None, command: bool) -> object:
    """'hello' and then the answer to a command, or the close code of a refusal."""
    from channels.testing import WebsocketCommunicator

    from printhost.asgi import application

    query = f"?apikey={key}" if key else ""
    client = WebsocketCommunicator(application, path + query)
    connected, _ = await client.connect(timeout=5)
    assert connected
    first = await client.receive_json_from(timeout=5)
    if first["type"] != "hello":
        close = await client.receive_output(timeout=5)
        return close["code"]
    if not command:
        await client.disconnect()
        return "hello"
    await client.send_json_to({"cmd": "M105"})
    while True:
        message = await client.receive_json_from(timeout=5)
        if message["type"] in ("queued", "error"):
            await client.disconnect()
            return message["type"]


@pytest.mark.django_db(transaction=True)
@pytest.mark.parametrize("caller", CALLERS)
def test_every_websocket_answers_every_caller_as_expected(
    caller: str, storage: Path, django_user_model: type
):
    import asyncio

    from channels.layers import channel_layers

    channel_layers.backends.clear()
    p = Printer.objects.create(name="P", slug="p", port="/dev/null", state="idle")
    q = Printer.objects.create(name="Q", slug="q", port="/dev/null", state="idle")
    setups = {
        "viewer": (Role.VIEWER, p, None),
        "operator": (Role.OPERATOR, p, None),
        "admin": (Role.ADMIN, None, None),
        "bound to q": (Role.OPERATOR, None, q),
    }
    key = "ph_" + "x" * 42 if caller == "wrong key" else None
    if caller in setups:
        role, printer, bound = setups[caller]
        user = django_user_model.objects.create_user("u", password="u")
        PrinterRole.objects.create(user=user, printer=printer, role=role)
        key = issue_key(user, "ws", printer=bound)[1]

    async def outcomes() -> tuple:
        watch = await _ws_outcome("/ws/printers/p/", key, command=False)
        watch_all = await _ws_outcome("/ws/printers/", key, command=False)
        send = None
        if watch == "hello":
            send = await _ws_outcome("/ws/printers/p/", key, command=True)
        return watch, watch_all, send

    try:
        got = asyncio.run(asyncio.wait_for(outcomes(), 30))
    finally:
        channel_layers.backends.clear()
    assert got == WS_EXPECTED[caller]
