"""What a websocket feed sends: new lines and states live, what a client missed when
it resumes by last id, filters, the all-printers feed, catching up from the log."""

from __future__ import annotations

import json
from collections.abc import Callable

import pytest
from channels.db import database_sync_to_async
from django.contrib.auth import get_user_model

from printers import broadcast, live
from printers.models import Printer
from printhost.models import PrinterRole, Role
from tests.live.conftest import add_lines, batches_then_a_lost_one, fail_log_reads
from tests.live.consumer_helpers import (
    TIMEOUT,
    connect,
    fresh_layer,  # noqa: F401 (autouse: a layer of its own for each test)
    line_ids,
    run,
    until,
    user_key,
)

pytestmark = pytest.mark.django_db(transaction=True)


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
