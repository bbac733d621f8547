"""App-key pairing (Cura's "Request..."): requests expire, each address may only ask a
few times at once, and the approver sees where a request came from and chooses the
printer and the role of the key, never above their own role.
"""

from __future__ import annotations

import json
from datetime import timedelta
from typing import TYPE_CHECKING

import pytest
from django.test import Client
from django.utils import timezone

from printers.models import Printer
from printhost.access import issue_key
from printhost.models import ApiKey, AppKeyRequest, PrinterRole, Role

if TYPE_CHECKING:
    from collections.abc import Callable


@pytest.fixture
def printers(make_printer: Callable[..., Printer]) -> tuple[Printer, Printer]:
    return (
        make_printer(slug="p", state=Printer.State.IDLE),
        make_printer(slug="q", state=Printer.State.IDLE),
    )


def person(django_user_model: type, name: str, role: int, printer: Printer) -> Client:
    """A logged-in browser of a user holding *role* on *printer*."""
    user = django_user_model.objects.create_user(name, password=name)
    PrinterRole.objects.create(user=user, printer=printer, role=role)
    browser = Client(enforce_csrf_checks=True)
    browser.force_login(user)
    browser.get("/accounts/login/")  # sets the CSRF cookie
    return browser


def ask(address: str = "192.0.2.7", path: str = "", **body: str) -> object:
    """The app's request; returns the reply (201 with Location, or the refusal)."""
    return Client(REMOTE_ADDR=address).post(
        f"{path}/plugin/appkeys/request",
        data=json.dumps({"app": "Cura", **body}),
        content_type="application/json",
    )


def decide(browser: Client, token: str, **body: object) -> object:
    return browser.post(
        f"/plugin/appkeys/decision/{token}",
        data=json.dumps({"decision": True, **body}),
        content_type="application/json",
        headers={"X-CSRFToken": browser.cookies["csrftoken"].value},
    )


def granted_key(location: str) -> str:
    reply = Client().get(location)
    assert reply.status_code == 200, reply.content
    return reply.json()["api_key"]


def test_a_request_expires_ten_minutes_after_it_was_made(
    printers: tuple[Printer, Printer], django_user_model: type
) -> None:
    boss = person(django_user_model, "boss", Role.OPERATOR, printers[0])
    asked = ask()
    row = AppKeyRequest.objects.get()
    AppKeyRequest.objects.filter(pk=row.pk).update(
        created_at=timezone.now() - timedelta(minutes=11)
    )  # still polled every few seconds: only its age ends it
    assert boss.get("/api/appkeys/pending").json()["data"] == []
    assert decide(boss, row.user_token).status_code == 404
    assert Client().get(asked["Location"]).status_code == 404
    assert AppKeyRequest.objects.get().state == AppKeyRequest.State.EXPIRED
    assert not ApiKey.objects.exists()


def test_one_address_may_have_only_a_few_requests_waiting(
    printers: tuple[Printer, Printer], django_user_model: type
) -> None:
    statuses = [ask("192.0.2.7").status_code for _ in range(4)]
    assert statuses == [201, 201, 201, 429]
    refused = ask("192.0.2.7")
    assert "192.0.2.7" in refused.json()["error"]
    assert ask("192.0.2.8").status_code == 201  # another address is not blocked
    boss = person(django_user_model, "boss", Role.OPERATOR, printers[0])
    first = AppKeyRequest.objects.filter(origin="192.0.2.7").order_by("pk").first()
    decide(boss, first.user_token, decision=False)
    assert ask("192.0.2.7").status_code == 201  # a decision frees a place


def test_the_approver_sees_the_requesting_address_and_the_expiry(
    printers: tuple[Printer, Printer], django_user_model: type
) -> None:
    boss = person(django_user_model, "boss", Role.OPERATOR, printers[0])
    ask("198.51.100.23", path="/p/p")
    [row] = boss.get("/api/appkeys/pending").json()["data"]
    assert row["origin"] == "198.51.100.23"
    assert row["printer"] == "p"
    made = AppKeyRequest.objects.get().created_at
    assert row["expires"] == (made + timedelta(minutes=10)).isoformat()


def test_the_approver_binds_the_key_to_a_printer_with_the_role_they_choose(
    printers: tuple[Printer, Printer], django_user_model: type
) -> None:
    p, q = printers
    boss = person(django_user_model, "boss", Role.OPERATOR, p)
    PrinterRole.objects.create(
        user=django_user_model.objects.get(username="boss"),
        printer=q,
        role=Role.OPERATOR,
    )
    asked = ask()
    token = AppKeyRequest.objects.get().user_token
    assert decide(boss, token, printer="p", role="viewer").status_code == 204
    key = granted_key(asked["Location"])
    app = Client(headers={"X-Api-Key": key})
    assert app.get("/printer/state/p").status_code == 200
    refused = app.post("/printer/send/p?cmd=M105")
    assert refused.status_code == 403
    assert "may act as viewer at most" in refused.json()["error"]
    assert app.get("/printer/state/q").status_code == 403  # bound to p
    stored = ApiKey.objects.get(prefix=key[3:13])
    assert (stored.printer, stored.role) == (p, Role.VIEWER)
    [listed] = boss.get("/api/keys").json()["data"]
    assert (listed["printer"], listed["role"]) == ("p", "viewer")
    assert "<td>viewer</td>" in boss.get("/account/").content.decode()


def test_an_approver_cannot_grant_more_than_their_own_role(
    printers: tuple[Printer, Printer], django_user_model: type
) -> None:
    boss = person(django_user_model, "boss", Role.OPERATOR, printers[0])
    asked = ask()
    token = AppKeyRequest.objects.get().user_token
    refused = decide(boss, token, printer="p", role="admin")
    assert refused.status_code == 403
    assert "at most your own role" in refused.json()["error"]
    refused = decide(boss, token, printer="q", role="viewer")
    assert refused.status_code == 403  # no role on q at all
    assert AppKeyRequest.objects.get().state == AppKeyRequest.State.PENDING
    assert Client().get(asked["Location"]).status_code == 202
    assert not ApiKey.objects.exists()


def test_a_named_viewer_who_approves_gives_a_viewer_key(
    printers: tuple[Printer, Printer], django_user_model: type
) -> None:
    vic = person(django_user_model, "vic", Role.VIEWER, printers[0])
    asked = ask(user="vic")
    token = AppKeyRequest.objects.get().user_token
    assert decide(vic, token).status_code == 204
    key = granted_key(asked["Location"])
    assert ApiKey.objects.get(prefix=key[3:13]).role == Role.VIEWER


def test_a_key_asked_through_a_printer_url_stays_bound_to_that_printer(
    printers: tuple[Printer, Printer], django_user_model: type
) -> None:
    boss = person(django_user_model, "boss", Role.OPERATOR, printers[0])
    ask(path="/p/p")
    token = AppKeyRequest.objects.get().user_token
    reply = decide(boss, token, printer="q")
    assert reply.status_code == 400
    assert "only be bound to that printer" in reply.json()["error"]


def test_an_api_key_cannot_approve_a_request(
    printers: tuple[Printer, Printer], django_user_model: type
) -> None:
    user = django_user_model.objects.create_user("boss", password="boss")
    PrinterRole.objects.create(user=user, printer=None, role=Role.ADMIN)
    _, raw = issue_key(user, "slicer", role=Role.VIEWER)
    ask()
    token = AppKeyRequest.objects.get().user_token
    reply = Client().post(
        f"/plugin/appkeys/decision/{token}",
        data=json.dumps({"decision": True, "role": "admin"}),
        content_type="application/json",
        headers={"X-Api-Key": raw},
    )
    assert reply.status_code == 403
    assert AppKeyRequest.objects.get().state == AppKeyRequest.State.PENDING
