"""Who may read /metrics: the scrape token when it is set, else an admin only."""

from __future__ import annotations

import pytest
from django.contrib.auth import get_user_model
from django.test import Client

from printers.models import Printer
from printhost.access import issue_key
from printhost.models import PrinterRole, Role

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("no_latency_history")]

TOKEN = "scrape-token-0123456789abcdef"


def user_with(role: int | None, name: str, *, printer: Printer | None = None) -> object:
    user = get_user_model().objects.create_user(name, is_superuser=role is None)
    if role is not None:
        PrinterRole.objects.create(user=user, role=role, printer=printer)
    return user


def get(client: Client, **headers: str) -> tuple[int, dict]:
    response = client.get("/metrics", headers=headers)
    body = response.json() if response.status_code != 200 else {}
    return response.status_code, body


@pytest.fixture
def with_token(settings):
    settings.PRINTHOST_METRICS_TOKEN = TOKEN


def test_the_token_gets_the_metrics(with_token, client):
    response = client.get("/metrics", headers={"Authorization": f"Bearer {TOKEN}"})
    assert response.status_code == 200
    assert b"printhost_jobs{" in response.content
    assert response["Content-Type"].startswith("text/plain")


def test_a_wrong_token_is_401(with_token, client):
    status, body = get(client, Authorization=f"Bearer {TOKEN}x")
    assert status == 401
    assert "wrong scrape token" in body["error"]


def test_no_token_is_401_with_a_bearer_challenge(with_token, client):
    response = client.get("/metrics")
    assert response.status_code == 401
    assert response["WWW-Authenticate"].startswith("Bearer")
    assert "PRINTHOST_METRICS_TOKEN" in response.json()["error"]


def test_with_a_token_set_an_admin_session_is_not_enough(with_token, client):
    client.force_login(user_with(None, "root"))
    assert get(client)[0] == 401


def test_with_a_token_set_an_admin_key_is_not_the_token(with_token, client):
    _, key = issue_key(user_with(None, "root"), "scrape")
    assert get(client, Authorization=f"Bearer {key}")[0] == 401


def test_without_a_token_an_admin_session_gets_the_metrics(client):
    client.force_login(user_with(Role.ADMIN, "boss"))
    assert get(client)[0] == 200


def test_without_a_token_an_admin_key_as_bearer_gets_the_metrics(client):
    _, key = issue_key(user_with(None, "root"), "scrape")
    assert get(client, Authorization=f"Bearer {key}")[0] == 200
    assert get(client, **{"X-Api-Key": key})[0] == 200


def test_a_viewer_is_403(client):
    client.force_login(user_with(Role.VIEWER, "watcher"))
    status, body = get(client)
    assert status == 403
    assert "admin role on every printer" in body["error"]


def test_an_admin_of_one_printer_is_403(client, make_printer):
    printer = make_printer(slug="p")
    client.force_login(user_with(Role.ADMIN, "local", printer=printer))
    assert get(client)[0] == 403


def test_an_admin_key_capped_below_admin_is_403(client):
    _, key = issue_key(user_with(None, "root"), "capped", role=Role.OPERATOR)
    assert get(client, Authorization=f"Bearer {key}")[0] == 403


def test_an_admin_key_bound_to_one_printer_is_403(client, make_printer):
    printer = make_printer(slug="p")
    _, key = issue_key(user_with(None, "root"), "bound", printer=printer)
    status, body = get(client, Authorization=f"Bearer {key}")
    assert status == 403
    assert "bound to one printer" in body["error"]


def test_anonymous_and_a_wrong_key_are_401(client):
    assert get(client)[0] == 401
    status, body = get(client, Authorization="Bearer ph_" + "x" * 42)
    assert status == 401
    assert "invalid or revoked" in body["error"]


def test_only_get_and_head_are_answered(client):
    client.force_login(user_with(None, "root"))
    assert client.head("/metrics").status_code == 200
    assert client.post("/metrics").status_code in (403, 405)  # CSRF, or the method


def test_a_refused_scrape_never_reads_the_body(with_token, client):
    body = b"x" * 4096
    response = client.generic("GET", "/metrics", body, content_type="text/plain")
    assert response.status_code == 401
    request = response.wsgi_request
    # Django keeps the body in `_body` once someone read it; nobody did.
    assert not hasattr(request, "_body")


@pytest.mark.parametrize("written", [f"{TOKEN}\n", f"  {TOKEN} "])
def test_a_token_set_with_stray_whitespace_still_matches(
    monkeypatch: pytest.MonkeyPatch, tmp_path, written: str
) -> None:
    """An environment file's line pasted with a newline or spaces around the token
    would otherwise lock every scrape out."""
    import runpy

    from tests.conftest import ROOT

    monkeypatch.setenv("PRINTHOST_DATA_DIR", str(tmp_path))
    monkeypatch.setenv("PRINTHOST_METRICS_TOKEN", written)
    loaded = runpy.run_path(str(ROOT / "printhost" / "settings.py"))
    assert loaded["PRINTHOST_METRICS_TOKEN"] == TOKEN
