"""A user's API keys: shown once, stored hashed, revocable, optionally bound."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import pytest

from printers.models import Printer
from printhost.access import find_key, hash_key, issue_key
from printhost.models import ApiKey, AuditEntry, PrinterRole, Role

if TYPE_CHECKING:
    from collections.abc import Callable


@pytest.fixture
def printer(make_printer: Callable[..., Printer]) -> Printer:
    return make_printer(slug="mk4")


@pytest.fixture
def alice(django_user_model: type, printer: Printer) -> object:
    user = django_user_model.objects.create_user("alice", password="alice")
    PrinterRole.objects.create(user=user, printer=printer, role=Role.OPERATOR)
    return user


def create(client: object, key: str, **body: object) -> object:
    return client.post(  # type: ignore[attr-defined]
        "/api/keys", data=json.dumps(body), content_type="application/json",
        headers={"X-Api-Key": key},
    )  # fmt: skip


def test_created_key_is_shown_once_and_stored_hashed(
    client: object, alice: object
) -> None:
    _, raw = issue_key(alice, "first")
    reply = create(client, raw, name="PrusaSlicer", printer="mk4")
    assert reply.status_code == 201
    data = reply.json()["data"]
    new = ApiKey.objects.get(pk=data["id"])
    assert new.key_hash == hash_key(data["key"]) and data["key"] not in new.key_hash
    assert data["printer"] == "mk4"
    assert find_key(data["key"]) is not None
    listed = client.get("/api/keys", headers={"X-Api-Key": raw}).json()["data"]  # type: ignore[attr-defined]
    assert {k["name"] for k in listed} == {"first", "PrusaSlicer"}
    assert all("key" not in k for k in listed)
    assert AuditEntry.objects.filter(action="key.create").exists()


def test_key_creation_errors(client: object, alice: object, printer: Printer) -> None:
    _, raw = issue_key(alice, "first")
    assert create(client, raw, name="  ").status_code == 400
    assert create(client, raw, name="x", printer="nope").status_code == 404
    assert create(client, raw).status_code == 422
    assert (
        client.post("/api/keys", data="{}", content_type="application/json").status_code
        == 401
    )  # type: ignore[attr-defined]


def test_a_bound_key_cannot_mint_an_unbound_one(
    client: object, alice: object, printer: Printer
) -> None:
    _, bound = issue_key(alice, "bound", printer=printer)
    assert create(client, bound, name="wider").status_code == 403
    assert create(client, bound, name="same", printer="mk4").status_code == 201


def test_revoked_key_stops_working(client: object, alice: object) -> None:
    _, raw = issue_key(alice, "first")
    victim, victim_raw = issue_key(alice, "old")
    reply = client.delete(f"/api/keys/{victim.pk}", headers={"X-Api-Key": raw})  # type: ignore[attr-defined]
    assert reply.status_code == 204
    assert client.get("/api/keys", headers={"X-Api-Key": victim_raw}).status_code == 401  # type: ignore[attr-defined]
    assert AuditEntry.objects.filter(action="key.revoke").exists()


def test_only_own_keys_unless_admin_of_everything(
    client: object, alice: object, django_user_model: type
) -> None:
    bob = django_user_model.objects.create_user("bob", password="bob")
    boss = django_user_model.objects.create_user("boss", password="boss")
    PrinterRole.objects.create(user=boss, printer=None, role=Role.ADMIN)
    bobs_key, _ = issue_key(bob, "bob's")
    _, alice_raw = issue_key(alice, "alice's")
    assert (
        client.delete(
            f"/api/keys/{bobs_key.pk}", headers={"X-Api-Key": alice_raw}
        ).status_code
        == 404
    )  # type: ignore[attr-defined]
    assert ApiKey.objects.get(pk=bobs_key.pk).revoked_at is None
    _, boss_raw = issue_key(boss, "boss")
    assert (
        client.delete(
            f"/api/keys/{bobs_key.pk}", headers={"X-Api-Key": boss_raw}
        ).status_code
        == 204
    )  # type: ignore[attr-defined]
    assert ApiKey.objects.get(pk=bobs_key.pk).revoked_at is not None


def test_appkey_decision_needs_a_logged_in_caller(client: object, db: None) -> None:
    asked = client.post(  # type: ignore[attr-defined]
        "/plugin/appkeys/request",
        data=json.dumps({"app": "Cura"}),
        content_type="application/json",
    )
    from printhost.models import AppKeyRequest

    token = AppKeyRequest.objects.get().user_token
    reply = client.post(  # type: ignore[attr-defined]
        f"/plugin/appkeys/decision/{token}", data=json.dumps({"decision": True}),
        content_type="application/json",
    )  # fmt: skip
    assert reply.status_code == 401
    assert client.get(asked["Location"]).status_code == 202  # type: ignore[attr-defined]


def test_viewer_without_being_named_cannot_approve(
    client: object, django_user_model: type, printer: Printer
) -> None:
    viewer = django_user_model.objects.create_user("vic", password="vic")
    PrinterRole.objects.create(user=viewer, printer=printer, role=Role.VIEWER)
    client.post(
        "/plugin/appkeys/request",
        data=json.dumps({"app": "Cura"}),
        content_type="application/json",
    )  # type: ignore[attr-defined]
    from printhost.models import AppKeyRequest

    token = AppKeyRequest.objects.get().user_token
    _, raw = issue_key(viewer, "v")
    reply = client.post(  # type: ignore[attr-defined]
        f"/plugin/appkeys/decision/{token}", data=json.dumps({"decision": True}),
        content_type="application/json", headers={"X-Api-Key": raw},
    )  # fmt: skip
    assert reply.status_code == 403
    assert AppKeyRequest.objects.get().state == "pending"


def test_pending_app_key_requests_are_capped(
    client: object, db: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    from printhost import appkeys

    monkeypatch.setattr(appkeys, "MAX_PENDING", 2)
    replies = [
        client.post(
            "/plugin/appkeys/request",
            data=json.dumps({"app": f"app{i}"}),
            content_type="application/json",
        ).status_code  # type: ignore[attr-defined]
        for i in range(3)
    ]
    assert replies == [201, 201, 429]
