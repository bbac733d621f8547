"""The websocket feeds in-process: auth on connect, resume, filters, commands, actions."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from channels.db import database_sync_to_async
from channels.layers import channel_layers
from channels.testing import WebsocketCommunicator
from django.contrib.auth import get_user_model
from django.utils import timezone

from printers import broadcast, live
from printers.models import Printer, QueuedCommand
from printhost.access import issue_key
from printhost.asgi import application
from printhost.models import ApiKey, AuditEntry, PrinterRole, Role
from tests.live.conftest import add_lines, batches_then_a_lost_one, fail_log_reads

pytestmark = pytest.mark.django_db(transaction=True)
TIMEOUT = 5


@pytest.fixture(autouse=True)
def fresh_layer() -> Iterator[None]:
    """Each test runs its own event loop: give it its own in-memory layer."""
    channel_layers.backends.clear()
    yield
    channel_layers.backends.clear()


@pytest.fixture
def printer(make_printer: Callable[..., Printer]) -> Printer:
    return make_printer(slug="mk3", state="idle")


def user_key(
    name: str,
    role: int | None,
    printer: Printer | None = None,
    bound: Printer | None = None,
) -> str:
    user = get_user_model().objects.create_user(name, password=name)
    if role is not None:
        PrinterRole.objects.create(user=user, role=role, printer=printer)
    return issue_key(user, "test", printer=bound)[1]


def run(coroutine: Any) -> Any:
    return asyncio.run(asyncio.wait_for(coroutine, 30))


async def connect(path: str, headers: list | None = None) -> WebsocketCommunicator:
    client = WebsocketCommunicator(application, path, headers=headers or [])
    connected, _ = await client.connect(timeout=TIMEOUT)
    assert connected
    return client


async def until(client: WebsocketCommunicator, kind: str) -> dict:
    while True:
        message = await client.receive_json_from(timeout=TIMEOUT)
        if message["type"] == kind:
            return message


async def closed_with(path: str, headers: list | None = None) -> tuple[dict, int]:
    client = await connect(path, headers)
    error = await client.receive_json_from(timeout=TIMEOUT)
    close = await client.receive_output(timeout=TIMEOUT)
    assert close["type"] == "websocket.close"
    return error, close["code"]


async def line_ids(client: WebsocketCommunicator, upto: int) -> list[int]:
    seen: list[int] = []
    while not seen or seen[-1] < upto:
        message = await until(client, "lines")
        seen += [line["id"] for line in message["lines"]]
    return seen


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


def test_a_viewer_gets_new_lines_and_state_changes_live(printer: Printer) -> None:
    key = user_key("viewer", Role.VIEWER, printer)
    add_lines(printer, 1, 3)

    async def scenario() -> tuple[dict, list[int], dict]:
        client = await connect(f"/ws/printers/mk3/?apikey={key}")
        hello = await client.receive_json_from(timeout=TIMEOUT)
        await database_sync_to_async(add_lines)(printer, 4, 6)
        ids = await line_ids(client, 6)
        await database_sync_to_async(Printer.objects.filter(pk=printer.pk).update)(
            state="printing", temperatures={"T0": [210.0, 210.0]}
        )
        state = await until(client, "state")
        await client.disconnect()
        return hello, ids, state

    hello, ids, state = run(scenario())
    assert hello["last"] == 3
    assert ids == [4, 5, 6], "no history without last=, then every new line once"
    assert state["state"] == "printing"


def test_a_client_resuming_with_last_gets_what_it_missed_then_the_live_lines(
    printer: Printer,
) -> None:
    key = user_key("viewer", Role.VIEWER)
    add_lines(printer, 1, 50)

    async def scenario() -> list[int]:
        client = await connect(f"/ws/printers/mk3/?apikey={key}&last=20")
        await client.receive_json_from(timeout=TIMEOUT)
        await database_sync_to_async(add_lines)(printer, 51, 60)
        ids = await line_ids(client, 60)
        await client.disconnect()
        return ids

    assert run(scenario()) == list(range(21, 61))


def test_a_resume_older_than_the_log_keeps_says_where_it_starts(
    printer: Printer,
) -> None:
    key = user_key("viewer", Role.VIEWER)
    add_lines(printer, 100, 105)

    async def scenario() -> tuple[dict, list[int]]:
        client = await connect(f"/ws/printers/mk3/?apikey={key}&last=7")
        await client.receive_json_from(timeout=TIMEOUT)
        notice = await client.receive_json_from(timeout=TIMEOUT)
        ids = await line_ids(client, 105)
        await client.disconnect()
        return notice, ids

    notice, ids = run(scenario())
    assert notice == {"type": "truncated", "first": 100, "printer": "mk3"}
    assert ids == list(range(100, 106))


def test_a_resume_further_back_than_a_page_gets_the_newest_page_and_says_so(
    printer: Printer,
) -> None:
    """`last=0` on a long log sends one page, not the whole log: the server would
    hold it all for a client that may never read it. Older lines are in the log's
    history (`/printer/response`)."""
    key = user_key("viewer", Role.VIEWER)
    newest = live.PAGE_LINES + 500
    add_lines(printer, 1, newest)

    async def scenario() -> tuple[dict, list[int]]:
        client = await connect(f"/ws/printers/mk3/?apikey={key}&last=0")
        await client.receive_json_from(timeout=TIMEOUT)
        notice = await client.receive_json_from(timeout=TIMEOUT)
        ids = await line_ids(client, newest)
        await client.disconnect()
        return notice, ids

    notice, ids = run(scenario())
    first = newest - live.PAGE_LINES + 1
    assert notice == {"type": "truncated", "first": first, "paged": True,
                      "printer": "mk3"}  # fmt: skip
    assert ids == list(range(first, newest + 1))


def test_the_filter_hides_kinds_but_not_non_maskable_lines(printer: Printer) -> None:
    key = user_key("viewer", Role.VIEWER)
    add_lines(printer, 1, 2, kind=2)
    add_lines(printer, 3, 3, kind=8)
    add_lines(printer, 4, 5, kind=4)

    async def scenario() -> list[dict]:
        client = await connect(f"/ws/printers/mk3/?apikey={key}&last=0&filter=6")
        await client.receive_json_from(timeout=TIMEOUT)
        message = await until(client, "lines")
        await client.disconnect()
        return message["lines"]

    assert [line["id"] for line in run(scenario())] == [3]


def test_a_bad_last_is_refused_with_a_message(printer: Printer) -> None:
    key = user_key("viewer", Role.VIEWER)
    error, code = run(closed_with(f"/ws/printers/mk3/?apikey={key}&last=abc"))
    assert code == 4400
    assert "last" in error["message"]


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


def test_the_all_printers_feed_covers_the_printers_the_caller_may_view(
    printer: Printer, make_printer: Callable[..., Printer]
) -> None:
    hidden = make_printer(slug="hidden")
    key = user_key("viewer", Role.VIEWER, printer)

    async def scenario() -> tuple[list[str], dict, dict]:
        client = await connect(f"/ws/printers/?apikey={key}")
        hello = await client.receive_json_from(timeout=TIMEOUT)
        await database_sync_to_async(add_lines)(hidden, 1, 2)
        await database_sync_to_async(add_lines)(printer, 1, 1)
        lines = await until(client, "lines")
        await client.send_json_to({"printer": "hidden", "cmd": "G28"})
        error = await until(client, "error")
        await client.disconnect()
        return [hello["printer"]], lines, error

    hellos, lines, error = run(scenario())
    assert hellos == ["mk3"]
    assert lines["printer"] == "mk3"
    assert "unknown printer 'hidden'" in error["message"]
    assert json.dumps(lines)  # plain JSON


def test_the_relay_stops_after_the_last_client_leaves(printer: Printer) -> None:
    key = user_key("viewer", Role.VIEWER)

    async def scenario() -> tuple[list[int], list[int]]:
        a = await connect(f"/ws/printers/mk3/?apikey={key}")
        b = await connect(f"/ws/printers/mk3/?apikey={key}")
        await a.receive_json_from(timeout=TIMEOUT)
        await b.receive_json_from(timeout=TIMEOUT)
        during = broadcast.relays_running()
        await a.disconnect()
        await b.disconnect()
        return during, broadcast.relays_running()

    during, after = run(scenario())
    assert during == [printer.pk]
    assert after == []


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


def test_the_all_printers_feed_resumes_each_printer_from_its_own_last_id(
    printer: Printer, make_printer: Callable[..., Printer]
) -> None:
    other = make_printer(slug="other")
    key = user_key("viewer", Role.VIEWER)
    add_lines(printer, 1, 5)
    add_lines(other, 1, 5)

    async def scenario() -> dict[str, list[int]]:
        client = await connect(f"/ws/printers/?apikey={key}&last.mk3=3&last.other=1")
        seen: dict[str, list[int]] = {"mk3": [], "other": []}
        while len(seen["mk3"]) < 2 or len(seen["other"]) < 4:
            message = await until(client, "lines")
            seen[message["printer"]] += [line["id"] for line in message["lines"]]
        await client.disconnect()
        return seen

    assert run(scenario()) == {"mk3": [4, 5], "other": [2, 3, 4, 5]}


@pytest.mark.usefixtures("quiet_feed")
def test_a_client_catches_up_from_the_log_when_a_live_message_is_lost(
    printer: Printer,
) -> None:
    """The channel layer is lossy: a client re-reads the log now and then."""
    key = user_key("viewer", Role.VIEWER)

    async def scenario() -> list[int]:
        client = await connect(f"/ws/printers/mk3/?apikey={key}&last=0")
        await until(client, "hello")
        await database_sync_to_async(add_lines)(printer, 1, 5)
        seen = await line_ids(client, 5)
        await client.disconnect()
        return seen

    assert run(scenario()) == [1, 2, 3, 4, 5]


@pytest.mark.usefixtures("quiet_feed")
def test_a_client_that_hears_live_batches_reads_the_log_only_once_they_stop(
    printer: Printer, log_reads: list[int]
) -> None:
    """While batches come, the periodic re-read is skipped (a lost one shows as a
    gap in the next); once they stop, the log is read again, so lines whose batch
    was lost after the last one heard still arrive."""
    key = user_key("viewer", Role.VIEWER)

    async def scenario() -> tuple[int, list[int]]:
        client = await connect(f"/ws/printers/mk3/?apikey={key}&last=0")
        await until(client, "hello")
        while_heard = await batches_then_a_lost_one(printer, log_reads)
        seen = await line_ids(client, 22)
        await client.disconnect()
        return while_heard, seen

    while_heard, seen = run(scenario())
    # Re-reading every period would be 5 or more; a period that began between two
    # batches on a busy machine may read once.
    assert while_heard <= 2
    assert seen == list(range(1, 23))


def test_the_all_printers_feed_follows_role_changes(
    printer: Printer,
    make_printer: Callable[..., Printer],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(live, "RECONCILE_SECONDS", 0.2)
    other = make_printer(slug="other", state="idle")
    key = user_key("watcher", Role.VIEWER, printer)
    user = get_user_model().objects.get(username="watcher")

    def swap_roles() -> None:
        PrinterRole.objects.filter(user=user, printer=printer).delete()
        PrinterRole.objects.create(user=user, role=Role.VIEWER, printer=other)

    async def scenario() -> tuple[dict, dict]:
        client = await connect(f"/ws/printers/?apikey={key}")
        first = await until(client, "hello")
        assert first["printer"] == "mk3"
        await database_sync_to_async(swap_roles)()
        gone = await until(client, "gone")
        added = await until(client, "hello")
        await client.disconnect()
        return gone, added

    gone, added = run(scenario())
    assert gone["printer"] == "mk3"
    assert added["printer"] == "other"


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
        return error, close["code"]

    error, code = run(scenario())
    assert code == 4401
    assert "revoked" in error["message"]


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


@pytest.mark.usefixtures("quiet_feed")
def test_a_failed_read_of_the_log_is_tried_again_the_next_period(
    printer: Printer, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The database locked or away for a moment: the client still gets the lines
    whose batch was lost (and its key is still checked) once it answers."""
    key = user_key("viewer", Role.VIEWER)
    failures: dict[str, list[int]] = {}

    async def scenario() -> list[int]:
        client = await connect(f"/ws/printers/mk3/?apikey={key}&last=0")
        await until(client, "hello")
        failures["left"] = fail_log_reads(monkeypatch, 2)
        await database_sync_to_async(add_lines)(printer, 1, 3)
        seen = await line_ids(client, 3)
        await client.disconnect()
        return seen

    assert run(scenario()) == [1, 2, 3]
    assert failures["left"] == [0], "the reads did not fail"
