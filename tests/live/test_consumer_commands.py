"""Commands and actions sent on a websocket feed: queued and audited for operators,
refused for viewers, bad JSON and an offline printer answered, ESP replies to the
asker only."""

from __future__ import annotations

import pytest
from channels.db import database_sync_to_async

from printers.models import Printer, QueuedCommand
from printhost.models import AuditEntry, Role
from tests.live.consumer_helpers import (
    TIMEOUT,
    connect,
    fresh_layer,  # noqa: F401 (autouse: a layer of its own for each test)
    run,
    until,
    user_key,
)

pytestmark = pytest.mark.django_db(transaction=True)


def test_an_operator_command_is_queued_and_audited(printer: Printer) -> None:
    key = user_key("op", Role.OPERATOR, printer)

    async def scenario() -> dict:
        client = await connect(f"/ws/printers/mk3/?apikey={key}")
        await client.receive_json_from(timeout=TIMEOUT)
        await client.send_json_to({"cmd": "G28"})
        queued = await until(client, "queued")
        await client.disconnect()
        return queued

    queued = run(scenario())
    row = QueuedCommand.objects.get(pk=queued["id"])
    assert (row.text, row.kind) == ("G28", "command")
    assert row.origin.startswith("websocket:op key ")
    entry = AuditEntry.objects.get(action="command")
    assert (entry.detail, entry.printer_id) == ("G28", printer.pk)


def test_a_viewer_cannot_send_commands_or_actions(printer: Printer) -> None:
    key = user_key("viewer", Role.VIEWER)

    async def scenario() -> list[dict]:
        client = await connect(f"/ws/printers/mk3/?apikey={key}")
        await client.receive_json_from(timeout=TIMEOUT)
        errors = []
        for message in ({"cmd": "G28"}, {"action": "abort"}):
            await client.send_json_to(message)
            errors.append(await until(client, "error"))
        await client.disconnect()
        return errors

    errors = run(scenario())
    assert all("operator role needed" in e["message"] for e in errors)
    assert not QueuedCommand.objects.exists()


def test_actions_and_the_emergency_stop_are_queued_and_audited(
    printer: Printer,
) -> None:
    key = user_key("op", Role.OPERATOR)

    async def scenario() -> dict:
        client = await connect(f"/ws/printers/mk3/?apikey={key}")
        await client.receive_json_from(timeout=TIMEOUT)
        for action in ("pause", "emergency_stop", "prompt:1", "dance", "prompt:x"):
            await client.send_json_to({"action": action})
        for _ in range(3):
            await until(client, "queued")
        errors = [await until(client, "error") for _ in range(2)]
        await client.disconnect()
        return errors

    unknown, bad_choice = run(scenario())
    rows = list(QueuedCommand.objects.values_list("kind", "text"))
    assert rows == [("action", "pause"), ("emergency", "M112"), ("action", "prompt:1")]
    assert "unknown action 'dance'" in unknown["message"]
    assert "button index" in bad_choice["message"]
    actions = set(AuditEntry.objects.values_list("action", flat=True))
    assert actions == {"pause", "emergency_stop", "prompt"}


def test_an_esp_reply_goes_to_the_asking_client_only(printer: Printer) -> None:
    key = user_key("op", Role.OPERATOR)

    async def scenario() -> tuple[dict, list]:
        asker = await connect(f"/ws/printers/mk3/?apikey={key}")
        other = await connect(f"/ws/printers/mk3/?apikey={key}")
        await asker.receive_json_from(timeout=TIMEOUT)
        await other.receive_json_from(timeout=TIMEOUT)
        await asker.send_json_to({"cmd": "[ESP701]"})
        queued = await until(asker, "queued")
        await database_sync_to_async(
            QueuedCommand.objects.filter(pk=queued["id"]).update
        )(state="done", reply="status: idle")
        reply = await until(asker, "reply")
        leftovers = []
        while not await other.receive_nothing(timeout=0.6):
            leftovers.append(await other.receive_json_from())
        await asker.disconnect()
        await other.disconnect()
        return reply, leftovers

    reply, leftovers = run(scenario())
    assert reply["reply"] == "status: idle"
    assert reply["cmd"] == "[ESP701]"
    assert all(m["type"] != "reply" for m in leftovers)


def test_bad_json_gets_an_error_and_the_connection_stays(printer: Printer) -> None:
    key = user_key("op", Role.OPERATOR)

    async def scenario() -> tuple[dict, dict]:
        client = await connect(f"/ws/printers/mk3/?apikey={key}")
        await client.receive_json_from(timeout=TIMEOUT)
        await client.send_to(text_data="{not json")
        error = await until(client, "error")
        await client.send_json_to({"cmd": "M105"})
        queued = await until(client, "queued")
        await client.disconnect()
        return error, queued

    error, queued = run(scenario())
    assert error["message"] == "send JSON objects"
    assert queued["cmd"] == "M105"


def test_a_command_follows_the_printer_state_as_it_is_now_not_at_connect(
    printer: Printer,
) -> None:
    key = user_key("op", Role.OPERATOR, printer)

    def set_state(state: str) -> None:
        Printer.objects.filter(pk=printer.pk).update(state=state)

    async def scenario() -> tuple[dict, dict]:
        client = await connect(f"/ws/printers/mk3/?apikey={key}")
        await until(client, "hello")
        await database_sync_to_async(set_state)("offline")
        await client.send_json_to({"cmd": "G28"})
        refused = await until(client, "error")
        await database_sync_to_async(set_state)("idle")
        await client.send_json_to({"cmd": "G28"})
        queued = await until(client, "queued")
        await client.disconnect()
        return refused, queued

    refused, queued = run(scenario())
    assert refused["message"] == "Printer offline"
    assert queued["cmd"] == "G28"
