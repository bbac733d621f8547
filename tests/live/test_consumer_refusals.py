"""Who may open a websocket feed, and the refusals (4401, 4403, 4404, 4400, 4429) of
the rest: origins, sessions, revoked keys, the cap on feeds per user."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from channels.db import database_sync_to_async
from channels.testing import WebsocketCommunicator
from django.utils import timezone

from printers import live
from printers.models import Printer
from printhost.asgi import application
from printhost.models import ApiKey, Role
from tests.live.consumer_helpers import (
    TIMEOUT,
    closed_with,
    connect,
    fresh_layer,  # noqa: F401 (autouse: a layer of its own for each test)
    run,
    until,
    user_key,
)

pytestmark = pytest.mark.django_db(transaction=True)


def test_anonymous_clients_are_refused_with_4401(printer: Printer) -> None:
    error, code = run(closed_with("/ws/printers/mk3/"))
    assert code == 4401
    assert "API key" in error["message"]


def test_a_wrong_key_is_refused_with_4401(printer: Printer) -> None:
    _, code = run(closed_with("/ws/printers/mk3/?apikey=ph_notakeyatallreally"))
    assert code == 4401


def test_a_user_without_a_role_is_refused_with_4403(printer: Printer) -> None:
    key = user_key("nobody", None)
    _, code = run(closed_with(f"/ws/printers/mk3/?apikey={key}"))
    assert code == 4403


def test_a_key_bound_to_another_printer_is_refused_with_4403(
    printer: Printer, make_printer: Callable[..., Printer]
) -> None:
    other = make_printer(slug="other")
    key = user_key("bound", Role.OPERATOR, bound=other)
    error, code = run(closed_with("/ws/printers/mk3/", [(b"x-api-key", key.encode())]))
    assert code == 4403
    assert "bound" in error["message"]


def test_an_unknown_printer_is_refused_with_4404(printer: Printer) -> None:
    key = user_key("viewer", Role.VIEWER)
    _, code = run(closed_with(f"/ws/printers/nope/?token={key}"))
    assert code == 4404


def test_a_foreign_origin_is_refused_but_no_origin_is_fine(printer: Printer) -> None:
    key = user_key("viewer", Role.VIEWER)

    async def scenario() -> None:
        foreign = WebsocketCommunicator(
            application, f"/ws/printers/mk3/?apikey={key}",
            headers=[(b"origin", b"http://evil.example")],
        )  # fmt: skip
        connected, _ = await foreign.connect(timeout=TIMEOUT)
        assert not connected
        own = await connect(
            f"/ws/printers/mk3/?apikey={key}", [(b"origin", b"http://localhost")]
        )
        assert (await own.receive_json_from(timeout=TIMEOUT))["type"] == "hello"
        await own.disconnect()

    run(scenario())


def test_a_session_user_is_accepted(printer: Printer) -> None:
    from django.test import Client

    user_key("watcher", Role.VIEWER)
    web = Client()
    assert web.login(username="watcher", password="watcher")
    cookie = f"sessionid={web.cookies['sessionid'].value}".encode()

    async def scenario() -> dict:
        client = await connect("/ws/printers/mk3/", [(b"cookie", cookie)])
        hello = await client.receive_json_from(timeout=TIMEOUT)
        await client.disconnect()
        return hello

    hello = run(scenario())
    assert hello["type"] == "hello"
    assert hello["state"] == "idle"


def test_a_bad_last_is_refused_with_a_message(printer: Printer) -> None:
    key = user_key("viewer", Role.VIEWER)
    error, code = run(closed_with(f"/ws/printers/mk3/?apikey={key}&last=abc"))
    assert code == 4400
    assert "last" in error["message"]


def test_a_revoked_key_is_disconnected_within_seconds(
    printer: Printer, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(live, "RECONCILE_SECONDS", 0.2)
    key = user_key("watcher", Role.VIEWER, printer)

    def revoke() -> None:
        ApiKey.objects.update(revoked_at=timezone.now())

    async def scenario() -> tuple[dict, int]:
        client = await connect(f"/ws/printers/mk3/?apikey={key}")
        await until(client, "hello")
        await database_sync_to_async(revoke)()
        error = await until(client, "error")
        close = await client.receive_output(timeout=TIMEOUT)
        # As the browser answers a close: the consumer leaves the printer's relay.
        await client.disconnect()
        return error, close["code"]

    error, code = run(scenario())
    assert code == 4401
    assert "revoked" in error["message"]


def test_a_user_past_the_feed_cap_is_refused_with_4429_until_one_closes(
    printer: Printer, settings
) -> None:
    settings.PRINTHOST_WS_MAX_PER_USER = 2
    key = user_key("viewer", Role.VIEWER)
    other = user_key("other", Role.VIEWER)
    path = f"/ws/printers/mk3/?apikey={key}"

    async def scenario() -> None:
        first, second = await connect(path), await connect(path)
        error, code = await closed_with(path)
        assert code == 4429 and "too many live feeds" in error["message"]
        # Another user is counted apart; a closed feed gives its place back.
        third = await connect(f"/ws/printers/mk3/?apikey={other}")
        await until(third, "hello")
        await first.disconnect()
        again = await connect(path)
        await until(again, "hello")
        for client in (second, third, again):
            await client.disconnect()

    run(scenario())
