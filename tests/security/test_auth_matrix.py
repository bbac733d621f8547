"""Every endpoint x every kind of caller gets the expected status.

Callers: anonymous, a wrong key, keys of a viewer / an operator of printer `p`, of an
admin of every printer, of a superuser, of an operator of every printer whose key is
bound to printer `q`, of an operator of `q` only; and the operator of `p` in a
browser session, with the CSRF token and without it.

Every call uses real objects (jobs, uploads, keys, pairing requests made for it) in
the state the call needs, so "allowed" means a 2xx answer, and "denied" means 401
(who are you?) or 403 (not you, not here, not this way). Each caller's call runs in
a savepoint that is rolled back, so every caller finds the same world.
"""

from __future__ import annotations

import base64
import io
from dataclasses import dataclass
from pathlib import Path

import pytest
from django.core.files.uploadedfile import SimpleUploadedFile
from django.db import transaction
from django.test import Client
from django.utils import timezone

from jobs import analysis_task, history, uploads
from jobs.analysis.thumbnails import png_encode
from jobs.farm.requirements import Requirements
from jobs.farm.storing import store_farm_upload
from jobs.models import Job
from jobs.resume.planning import make_plan, request_plan
from jobs.services import enqueue_job
from printers.models import Printer
from printhost.access import issue_key
from printhost.appkeys import open_request
from printhost.models import ApiKey, PrinterRole, Role

PUBLIC, VIEWER, OPERATOR, ADMIN = 0, Role.VIEWER, Role.OPERATOR, Role.ADMIN
SAFE = ("GET", "HEAD", "OPTIONS")


@dataclass(frozen=True)
class Endpoint:
    method: str
    path: str  # {stored} {done} {file} {upload} {own_key} {app_token} {user_token}
    # {entry} {running} {farm}
    role: int
    #: "p": acts on printer p (a key bound to q is refused); "any": a role anywhere
    #: will do; "unbound": a role anywhere, but a key bound to a printer is refused;
    #: "every": a role on every printer, and a key bound to a printer is refused.
    scope: str = "p"
    #: "json:{...}", "jsonf:{{...{stored}}}" (formatted like the path), "file"
    #: (multipart G-code), "raw".
    body: str = ""
    #: The printer's state the call needs: "", "printing", "paused", "waitstart",
    #: "prompt" (paused in M600, the firmware's prompt shown).
    state: str = ""
    #: A GET that changes something: only API keys may (sessions must POST).
    acts: bool = False
    #: Checked by CallerAuth (a session's unsafe call needs the CSRF token).
    csrf: bool = True
    #: Only people decide (a browser session), never a key.
    people_only: bool = False

    def __str__(self) -> str:
        return f"{self.method} {self.path}"


def ep(method: str, path: str, role: int, **options: object) -> Endpoint:
    return Endpoint(method, path, role, **options)  # type: ignore[arg-type]


PASSIVE = 'json:{"passive": true}'
ENDPOINTS = [
    # OctoPrint dialect (slicers); /p/p/ names the printer.
    ep("GET", "/api/version", PUBLIC, scope="any"),
    # A passive login reports the caller's session or key, so it needs one.
    ep("POST", "/api/login", VIEWER, scope="any", body=PASSIVE, csrf=False),
    ep("GET", "/api/server", VIEWER, scope="any"),
    ep("GET", "/api/currentuser", VIEWER, scope="any"),
    ep("GET", "/api/settings", VIEWER, scope="any"),
    ep("GET", "/p/p/api/printerprofiles", VIEWER),
    ep("GET", "/p/p/api/connection", VIEWER),
    ep("POST", "/p/p/api/connection", OPERATOR, body='json:{"command": "connect"}'),
    ep("GET", "/p/p/api/printer", VIEWER),
    ep("POST", "/p/p/api/printer/command", OPERATOR, body='json:{"commands": ["M105"]}'),
    ep("GET", "/p/p/api/printer/tool", VIEWER),
    ep("POST", "/p/p/api/printer/tool", OPERATOR, body='json:{"command": "target", "targets": {"tool0": 200}}'),
    ep("GET", "/p/p/api/printer/bed", VIEWER),
    ep("POST", "/p/p/api/printer/bed", OPERATOR, body='json:{"command": "target", "target": 60}'),
    ep("POST", "/p/p/api/printer/printhead", OPERATOR, body='json:{"command": "feedrate", "factor": 100}'),
    ep("POST", "/p/p/api/files/local", OPERATOR, body="file"),
    ep("GET", "/p/p/api/files/local/{file}", VIEWER),
    ep("GET", "/p/p/api/files", VIEWER),
    ep("GET", "/p/p/api/files/local", VIEWER),
    ep("GET", "/p/p/api/files/thumbnail/{stored}/16x16.png", VIEWER),
    ep("POST", "/p/p/api/files/local/{file}", OPERATOR, body='json:{"command": "select"}'),
    ep("GET", "/p/p/api/job", VIEWER),
    ep("POST", "/p/p/api/job", OPERATOR, body='json:{"command": "cancel"}', state="printing"),
    ep("GET", "/p/p/api/files/sdcard", VIEWER),
    ep("POST", "/p/p/api/files/sdcard", OPERATOR, body="file"),
    ep("POST", "/p/p/api/files/sdcard/CUBE.GCO", OPERATOR,
       body='json:{"command": "select", "print": true}'),
    ep("GET", "/p/p/api/printer/sd", VIEWER),
    ep("POST", "/p/p/api/printer/sd", OPERATOR, body='json:{"command": "refresh"}'),
    # Moonraker dialect.
    ep("GET", "/p/p/server/info", VIEWER),
    ep("GET", "/p/p/server/files/metadata?filename={file}", VIEWER),
    ep("GET", "/p/p/server/files/gcodes/.thumbs/{stored}/16x16.png", VIEWER),
    ep("POST", "/p/p/server/files/upload", OPERATOR, body="file"),
    ep("POST", "/p/p/printer/print/start?filename={file}", OPERATOR),
    ep("POST", "/p/p/printer/print/pause", OPERATOR, state="printing"),
    ep("POST", "/p/p/printer/print/resume", OPERATOR, state="paused"),
    ep("POST", "/p/p/printer/print/cancel", OPERATOR, state="printing"),
    ep("POST", "/p/p/printer/emergency_stop", OPERATOR),
    ep("GET", "/p/p/server/history/list", VIEWER),
    ep("GET", "/p/p/server/history/job?uid={entry}", VIEWER),
    ep("GET", "/p/p/server/history/totals", VIEWER),
    # App-key pairing (Cura) and the user's keys.
    ep("GET", "/plugin/appkeys/probe", PUBLIC, scope="any"),
    ep("POST", "/plugin/appkeys/request", PUBLIC, scope="any", body='json:{"app": "Cura"}'),
    ep("GET", "/plugin/appkeys/request/{app_token}", PUBLIC, scope="any"),
    # Everyone sees the requests that name them; operators see all.
    ep("GET", "/api/appkeys/pending", VIEWER, scope="any"),
    ep(
        "POST", "/plugin/appkeys/decision/{user_token}", OPERATOR, scope="any",
        body='json:{"decision": true}', people_only=True,
    ),
    ep("GET", "/api/keys", VIEWER, scope="any"),
    # A key bound to one printer cannot mint a key for every printer.
    ep("POST", "/api/keys", VIEWER, scope="unbound", body='json:{"name": "more"}'),
    ep("DELETE", "/api/keys/{own_key}", VIEWER, scope="any"),
    # The seed's /printer/ API and the host extras.
    ep("GET", "/printer/list", VIEWER, scope="any"),
    ep("GET", "/printer/info", VIEWER, scope="any"),
    ep("GET", "/printer/send/p?cmd=M105", OPERATOR, acts=True),
    ep("POST", "/printer/send/p?cmd=M105", OPERATOR),
    ep("GET", "/printer/response/p?start=0", VIEWER),
    ep("GET", "/printer/job/p?a=list", VIEWER),
    ep("GET", "/printer/job/p?a=pause", OPERATOR, state="printing", acts=True),
    ep("POST", "/printer/job/p?a=pause", OPERATOR, state="printing"),
    ep("GET", "/printer/job/p?a=start&id={stored}", OPERATOR, acts=True),
    ep("POST", "/printer/job/p?a=start&id={stored}", OPERATOR),
    ep("POST", "/printer/job/p?a=reprint&id={done}", OPERATOR),
    ep("GET", "/printer/job/p?a=delete&id={done}", OPERATOR, acts=True),
    ep("POST", "/printer/job/p?a=delete&id={done}", OPERATOR),
    ep("POST", "/printer/job/p?a=upload", OPERATOR, body="file"),
    ep("GET", "/printer/state/p", VIEWER),
    ep("GET", "/printer/temperatures/p", VIEWER),
    # Print history: each caller reads the printers it may view.
    ep("GET", "/printer/history", VIEWER, scope="any"),
    ep("GET", "/printer/history?format=csv", VIEWER, scope="any"),
    ep("GET", "/printer/history/totals?group=printer", VIEWER, scope="any"),
    ep("POST", "/printer/connect/p", OPERATOR),
    ep("POST", "/printer/disconnect/p", OPERATOR),
    ep("POST", "/printer/bedclear/p", OPERATOR, state="waitstart"),
    ep("POST", "/printer/emergency/p", OPERATOR),
    ep("POST", "/printer/prompt/p", OPERATOR, body='json:{"choice": 0}', state="prompt"),
    ep("POST", "/printer/queue/p", OPERATOR, body='json:{"order": []}'),
    ep("GET", "/printer/sd/p", VIEWER),
    ep("POST", "/printer/sd/p/refresh", OPERATOR),
    ep("POST", "/printer/sd/p/print", OPERATOR, body='json:{"name": "CUBE.GCO"}'),
    ep("POST", "/printer/sd/p/upload", OPERATOR, body='jsonf:{{"job": {stored}}}'),
    ep("POST", "/printer/sd/p/delete", OPERATOR, body='json:{"name": "CUBE.GCO"}'),
    ep("GET", "/printer/analysis/p/{stored}", VIEWER),
    ep("POST", "/printer/analysis/p/{stored}/again", OPERATOR),
    ep("GET", "/printer/thumbnail/p/{stored}/16x16.png", VIEWER),
    ep("GET", "/printer/toolpath/p/{stored}/0", VIEWER),
    ep("GET", "/printer/resume/p?id={stopped}", VIEWER),
    ep("GET", "/printer/resume/p?plan={plan}", VIEWER),
    ep("POST", "/printer/resume/p", OPERATOR, body='jsonf:{{"id": {stopped}}}'),
    ep("POST", "/printer/resume/p/start", OPERATOR, body='jsonf:{{"plan": {plan}}}'),
    ep("GET", "/printer/objects/p?id={stored}", VIEWER),
    ep("POST", "/printer/objects/p", OPERATOR, body='jsonf:{{"id": {running}, "object": "a"}}', state="printing"),
    ep("POST", "/printer/model/p", OPERATOR, body="file"),
    ep("GET", "/printer/api/p?a=listModelGroups", VIEWER),
    ep("POST", "/printer/api/p?a=listModelGroups", VIEWER),
    ep("GET", '/printer/api/p?a=send&data={{"cmd": "M105"}}', OPERATOR, acts=True),
    ep("POST", '/printer/api/p?a=send&data={{"cmd": "M105"}}', OPERATOR),
    ep("GET", "/printer/api/p?a=stopJob", OPERATOR, state="printing", acts=True),
    ep("POST", "/printer/api/p?a=continueJob", OPERATOR, state="paused"),
    ep("POST", "/printer/upload/p?name=a.gcode&size=5", OPERATOR),
    ep("GET", "/printer/upload/p/{upload}", OPERATOR),
    ep("HEAD", "/printer/upload/p/{upload}", OPERATOR),
    ep("PATCH", "/printer/upload/p/{upload}", OPERATOR, body="raw"),
    ep("DELETE", "/printer/upload/p/{upload}", OPERATOR),
    # The admin role.
    ep("GET", "/printer/config/p", ADMIN),
    ep("PATCH", "/printer/config/p", ADMIN, body='json:{"auto_start": true}'),
    ep("GET", "/api/users", ADMIN, scope="any"),
    ep("POST", "/api/users/viewer/role", ADMIN, scope="any", body='json:{"role": "viewer"}'),
    # The farm: a job may go to any printer, so a role on every printer, and no
    # key bound to one; what a printer has loaded is its operator's.
    ep("GET", "/printer/farm", VIEWER, scope="every"),
    ep("GET", "/printer/farm/{farm}", VIEWER, scope="every"),
    ep("PATCH", "/printer/farm/{farm}", OPERATOR, scope="every", body='json:{"priority": 3}'),
    ep("POST", "/printer/farm/{farm}/cancel", OPERATOR, scope="every"),
    ep("GET", "/printer/job/farm?a=list", VIEWER, scope="every"),
    ep("POST", "/printer/job/farm?a=upload&material=PLA", OPERATOR, scope="every", body="file"),
    ep("POST", "/p/farm/api/files/local", OPERATOR, scope="every", body="file"),
    ep("POST", "/p/farm/server/files/upload", OPERATOR, scope="every", body="file"),
    ep("POST", "/printer/loaded/p", OPERATOR, body='json:{"material": "PETG"}'),
    # Prometheus' scrape (no PRINTHOST_METRICS_TOKEN here): admins of every printer.
    ep("GET", "/metrics", ADMIN, scope="any"),
]  # fmt: skip

KEY_CALLERS = [
    "anonymous", "wrong key", "viewer", "operator", "admin", "superuser",
    "bound to q", "operator of q",
]  # fmt: skip
SESSIONS = ["session with CSRF", "session without CSRF"]
CALLERS = KEY_CALLERS + SESSIONS

#: The role each caller holds on p, and the best it holds anywhere (None: none).
HELD = {
    "viewer": (VIEWER, VIEWER),
    "operator": (OPERATOR, OPERATOR),
    "admin": (ADMIN, ADMIN),
    "superuser": (ADMIN, ADMIN),
    "bound to q": (None, OPERATOR),
    "operator of q": (None, OPERATOR),
    "session with CSRF": (OPERATOR, OPERATOR),
    "session without CSRF": (OPERATOR, OPERATOR),
}


def expected(caller: str, endpoint: Endpoint) -> str:
    if endpoint.role == PUBLIC:
        return "allowed"
    if caller in ("anonymous", "wrong key"):
        return "401"
    session = caller in SESSIONS
    if session and endpoint.acts and endpoint.method in SAFE:
        return "403"
    unsafe = endpoint.method not in SAFE
    if caller == "session without CSRF" and unsafe and endpoint.csrf:
        return "403"
    if endpoint.people_only and not session:
        return "403"
    if caller == "bound to q" and endpoint.scope in ("p", "unbound", "every"):
        return "403"
    on_p, anywhere = HELD[caller]
    held = on_p if endpoint.scope == "p" else anywhere
    every = (endpoint.role == ADMIN and endpoint.scope == "any") or (
        endpoint.scope == "every"
    )
    if every:
        held = ADMIN if caller in ("admin", "superuser") else None  # every printer
    return "allowed" if held is not None and held >= endpoint.role else "403"


@dataclass
class World:
    p: Printer
    q: Printer
    users: dict[str, object]
    keys: dict[str, str]
    source: Path


@pytest.fixture
def world(db: None, storage: Path, tmp_path: Path, django_user_model: type) -> World:
    p = Printer.objects.create(name="P", slug="p", port="/dev/null", state="idle")
    q = Printer.objects.create(name="Q", slug="q", port="/dev/null", state="idle")
    users, keys = {}, {}
    for name, role, printer, bound in (
        ("viewer", Role.VIEWER, p, None),
        ("operator", Role.OPERATOR, p, None),
        ("admin", Role.ADMIN, None, None),
        ("superuser", None, None, None),
        ("bound to q", Role.OPERATOR, None, q),
        ("operator of q", Role.OPERATOR, q, None),
    ):
        user = django_user_model.objects.create_user(
            name.replace(" ", "_"), password=name, is_superuser=role is None
        )
        if role is not None:
            PrinterRole.objects.create(user=user, printer=printer, role=role)
        users[name] = user
        keys[name] = issue_key(user, "matrix", printer=bound)[1]
    keys["wrong key"] = "ph_" + "x" * 42
    for name in SESSIONS:
        users[name] = users["operator"]
    source = tmp_path / "cube.gcode"
    picture = base64.b64encode(png_encode(16, 16, bytes(4 * 16 * 16))).decode()
    thumbnail = (
        f"; thumbnail begin 16x16 {len(picture)}\n; {picture}\n; thumbnail end\n"
    )
    objects = "; printing object a\nG1 X5 E1\n; printing object b\nG1 X9 E2\n"
    source.write_text(thumbnail + "G28\nG1 X1\nG1 Z0.2\n" + objects)
    return World(p, q, users, keys, source)


def objects_for(world: World, caller: str, state: str) -> dict[str, object]:
    """What the call needs, made for this caller (in its savepoint)."""
    p = world.p
    stored = enqueue_job(p, world.source, name="cube.gcode", queue=False)
    analysis_task.run(stored.analysis_id)  # as the Celery worker would (its thumbnail)
    done = enqueue_job(p, world.source, name="done.gcode", queue=False)
    Job.objects.filter(pk=done.pk).update(
        state=Job.State.COMPLETED, started_at=timezone.now(), finished_at=timezone.now()
    )
    entry = history.record_run(done.pk)
    # A run that stopped (its file analysed, with stored's), and a plan to resume it.
    stopped = enqueue_job(p, world.source, name="stopped.gcode", queue=False)
    Job.objects.filter(pk=stopped.pk).update(state=Job.State.INTERRUPTED, lines_acked=2)
    stopped.refresh_from_db()
    plan = request_plan(stopped)
    make_plan(plan.pk)
    running = None
    if state in ("printing", "paused"):
        running = enqueue_job(p, world.source, name="running.gcode")
        Job.objects.filter(pk=running.pk).update(state=state)
    if state == "prompt":
        prompt = {
            "message": "Nozzle Parked",
            "choices": ["Continue"],
            "answerable": True,
        }
        Printer.objects.filter(pk=p.pk).update(
            state="paused", machine_status={"prompt": prompt}
        )
    elif state:
        Printer.objects.filter(pk=p.pk).update(state=state)
    user = world.users.get(caller) or world.users["operator"]
    upload = uploads.open_upload(p, "part.gcode", user=user)
    farm_job = store_farm_upload(
        io.BytesIO(b"G28\nG1 X1\n"), name="farm.gcode", requirements=Requirements()
    )
    request = open_request("Cura", origin=f"192.0.2.{len(caller)}")
    return {
        "stored": stored.pk,
        "done": done.pk,
        "stopped": stopped.pk,
        "plan": plan.pk,
        "file": stored.file.rsplit("/", 1)[-1],
        "upload": upload.pk,
        "own_key": issue_key(user, "spare")[0].pk,
        "app_token": request.app_token,
        "user_token": request.user_token,
        "entry": entry.uid if entry else "",
        "running": running.pk if running else "",
        "farm": farm_job.pk,
    }


def client_of(world: World, caller: str) -> tuple[Client, dict[str, str]]:
    """A client and the headers it sends with every request."""
    if caller not in SESSIONS:
        key = world.keys.get(caller)
        return Client(), ({"X-Api-Key": key} if key else {})
    browser = Client(enforce_csrf_checks=True)
    browser.force_login(world.users[caller])
    browser.get("/accounts/login/")  # a page that sets the CSRF cookie
    if caller == "session without CSRF":
        return browser, {}
    return browser, {"X-CSRFToken": browser.cookies["csrftoken"].value}


def call(world: World, caller: str, endpoint: Endpoint) -> int:
    """The status *caller* gets; everything the call changed is rolled back."""
    with transaction.atomic():
        names = objects_for(world, caller, endpoint.state)
        client, headers = client_of(world, caller)
        kwargs: dict = {"headers": headers}
        if endpoint.body.startswith("json:"):
            kwargs |= {"data": endpoint.body[5:], "content_type": "application/json"}
        elif endpoint.body.startswith("jsonf:"):
            data = endpoint.body[6:].format(**names)
            kwargs |= {"data": data, "content_type": "application/json"}
        elif endpoint.body == "file":
            kwargs["data"] = {
                part: SimpleUploadedFile("cube.gcode", b"G28\nG1 X1\n")
                for part in ("file", "filename")  # Repetier's name, the others'
            } | {"print": "false"}
        elif endpoint.body == "raw":
            kwargs |= {
                "data": b"G28\n",
                "content_type": "application/offset+octet-stream",
            }
            headers["Upload-Offset"] = "0"
        method = getattr(client, endpoint.method.lower())
        status = method(endpoint.path.format(**names), **kwargs).status_code
        transaction.set_rollback(True)
    return status


def outcome(status: int) -> str:
    if 200 <= status < 300:
        return "allowed"
    return str(status)


@pytest.mark.parametrize("endpoint", ENDPOINTS, ids=str)
def test_every_endpoint_answers_every_caller_as_expected(
    endpoint: Endpoint, world: World
):
    wrong = []
    for caller in CALLERS:
        status = call(world, caller, endpoint)
        want = expected(caller, endpoint)
        if outcome(status) != want:
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


def test_api_keys_are_not_stored_in_clear(world: World):
    stored = list(ApiKey.objects.values_list("prefix", "key_hash", "name"))
    for raw in world.keys.values():
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
    "superuser": ("hello", "hello", "queued"),
    "bound to q": (4403, "hello", None),
    "operator of q": (4403, "hello", None),
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
@pytest.mark.parametrize("caller", KEY_CALLERS)
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
        "superuser": (None, None, None),
        "bound to q": (Role.OPERATOR, None, q),
        "operator of q": (Role.OPERATOR, q, None),
    }
    key = "ph_" + "x" * 42 if caller == "wrong key" else None
    if caller in setups:
        role, printer, bound = setups[caller]
        user = django_user_model.objects.create_user(
            "u", password="u", is_superuser=role is None
        )
        if role is not None:
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
