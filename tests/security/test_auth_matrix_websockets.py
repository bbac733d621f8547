"""Every websocket feed x every kind of key gets the expected answer: watching needs
the viewer role on the printer, commands the operator's."""

from __future__ import annotations

from pathlib import Path

import pytest

from printers.models import Printer
from printhost.access import issue_key
from printhost.models import PrinterRole, Role
from tests.security.auth_matrix_helpers import KEY_CALLERS

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
