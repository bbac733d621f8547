"""Every HTTP endpoint x every kind of caller gets the expected status.

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
from tests.security.auth_matrix_helpers import (
    CALLERS,
    ENDPOINTS,
    SESSIONS,
    Endpoint,
    expected,
)


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
