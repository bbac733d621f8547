"""The terminal re-reads the log now and then, so a lost live message costs nothing."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable, Iterator

import pytest
from channels.db import database_sync_to_async
from channels.layers import channel_layers
from django.contrib.auth import get_user_model
from django.utils import timezone

from printers import live
from printers.models import Printer, ResponseLine
from printers.terminal import Session
from printhost.access import issue_key
from printhost.models import ApiKey, PrinterRole, Role
from tests.live.conftest import add_lines, batches_then_a_lost_one, fail_log_reads

pytestmark = pytest.mark.django_db(transaction=True)


@pytest.fixture(autouse=True)
def fresh_layer() -> Iterator[None]:
    """Each test runs its own event loop: give it its own in-memory layer."""
    channel_layers.backends.clear()
    yield
    channel_layers.backends.clear()


def revoke_keys() -> None:
    ApiKey.objects.update(revoked_at=timezone.now())


async def open_session(
    printer: Printer, key: str
) -> tuple[asyncio.Server, asyncio.StreamReader, asyncio.StreamWriter, bytes]:
    """A terminal server for *printer* on a free port, a client that sent *key*,
    and the greeting it got (the session watches the printer from then on)."""
    server = await asyncio.start_server(
        lambda r, w: Session(printer, r, w).run(), "127.0.0.1", 0
    )
    port = server.sockets[0].getsockname()[1]
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(f"{key}\n".encode())
    greeting = await asyncio.wait_for(reader.readline(), 10)
    return server, reader, writer, greeting


@pytest.fixture
def watched(make_printer: Callable[..., Printer]) -> tuple[Printer, str]:
    """Printer mk3 and the API key of a user who may watch it."""
    printer = make_printer(slug="mk3", state="idle")
    user = get_user_model().objects.create_user("watcher", password="watcher")
    PrinterRole.objects.create(user=user, printer=printer, role=Role.VIEWER)
    return printer, issue_key(user, "terminal")[1]


@pytest.mark.usefixtures("quiet_feed")
def test_a_terminal_client_catches_up_from_the_log_when_a_live_message_is_lost(
    watched: tuple[Printer, str],
) -> None:
    printer, key = watched

    async def scenario() -> list[str]:
        server, reader, writer, greeting = await open_session(printer, key)
        assert greeting.startswith(b"// printhost: mk3 as watcher"), greeting
        await database_sync_to_async(add_lines)(printer, 1, 3)
        got = [
            (await asyncio.wait_for(reader.readline(), 10)).decode() for _ in range(3)
        ]
        writer.close()
        server.close()
        return got

    assert asyncio.run(asyncio.wait_for(scenario(), 30)) == [
        "echo 1\n",
        "echo 2\n",
        "echo 3\n",
    ]


@pytest.mark.usefixtures("quiet_feed")
def test_a_terminal_that_hears_live_batches_reads_the_log_only_once_they_stop(
    watched: tuple[Printer, str], log_reads: list[int]
) -> None:
    """As the websocket feed: no periodic re-read while batches come, and the lines
    of a batch lost after the last one heard still arrive from the log."""
    printer, key = watched

    async def scenario() -> tuple[int, list[str]]:
        server, reader, writer, _ = await open_session(printer, key)
        while_heard = await batches_then_a_lost_one(printer, log_reads)
        got = [
            (await asyncio.wait_for(reader.readline(), 10)).decode() for _ in range(22)
        ]
        writer.close()
        server.close()
        return while_heard, got

    while_heard, got = asyncio.run(asyncio.wait_for(scenario(), 30))
    # Re-reading every period would be 5 or more; a period that began between two
    # batches on a busy machine may read once.
    assert while_heard <= 2
    assert got == [f"echo {i}\n" for i in range(1, 23)]


def test_a_terminal_session_ends_when_its_key_is_revoked(
    watched: tuple[Printer, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    printer, key = watched
    monkeypatch.setattr(live, "RECONCILE_SECONDS", 0.2)

    async def scenario() -> tuple[bytes, bytes]:
        server, reader, writer, _ = await open_session(printer, key)
        await database_sync_to_async(revoke_keys)()
        said = await asyncio.wait_for(reader.readline(), 10)
        end = await asyncio.wait_for(reader.read(), 10)
        writer.close()
        server.close()
        return said, end

    said, end = asyncio.run(asyncio.wait_for(scenario(), 30))
    assert said == b"error: the API key was revoked\n"
    assert end == b"", "the session should have been closed"


def test_a_command_after_the_key_was_revoked_is_refused_and_ends_the_session(
    make_printer: Callable[..., Printer], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Checked at each command, not only now and then: a session that never gets to
    its reconcile (its client stopped reading) sends nothing more either."""
    from printers.models import QueuedCommand

    printer = make_printer(slug="mk3", state="idle")
    user = get_user_model().objects.create_user("operator", password="operator")
    PrinterRole.objects.create(user=user, printer=printer, role=Role.OPERATOR)
    key = issue_key(user, "terminal")[1]
    monkeypatch.setattr(live, "RECONCILE_SECONDS", 3600)

    async def scenario() -> tuple[bytes, bytes]:
        server, reader, writer, _ = await open_session(printer, key)
        await database_sync_to_async(revoke_keys)()
        writer.write(b"M117 after the revocation\n")
        said = await asyncio.wait_for(reader.readline(), 10)
        end = await asyncio.wait_for(reader.read(), 10)
        writer.close()
        server.close()
        return said, end

    said, end = asyncio.run(asyncio.wait_for(scenario(), 30))
    assert said == b"error: the API key was revoked\n"
    assert end == b"", "the session should have been closed"
    assert not QueuedCommand.objects.filter(text__startswith="M117").exists()


def test_a_client_that_reads_nothing_is_disconnected(
    watched: tuple[Printer, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Its output would pile up, and its session, stuck writing, would no longer see
    its key revoked."""
    from printers import terminal

    printer, key = watched
    monkeypatch.setattr(live, "RECONCILE_SECONDS", 0.1)
    monkeypatch.setattr(terminal, "DRAIN_SECONDS", 0.5)
    long_line = "x" * 2000

    def flood(batch: int) -> None:  # 4 MB more the client never reads
        ResponseLine.objects.bulk_create(
            ResponseLine(
                printer=printer, seq=i, time=timezone.now(), text=long_line, kind=4
            )
            for i in range(batch * 2000 + 1, batch * 2000 + 2001)
        )

    async def scenario() -> bool:
        ended = asyncio.Event()

        async def session(r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
            try:
                await Session(printer, r, w).run()
            finally:
                ended.set()

        server = await asyncio.start_server(session, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        writer.write(f"{key}\n".encode())
        await asyncio.wait_for(reader.readline(), 10)  # the greeting, then no more
        try:
            for batch in range(30):  # until the session gives up on the client
                await database_sync_to_async(flood)(batch)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(ended.wait(), 1)
                if ended.is_set():
                    break
        finally:
            writer.close()
            server.close()
        return ended.is_set()

    assert asyncio.run(asyncio.wait_for(scenario(), 60))


@pytest.mark.usefixtures("quiet_feed")
def test_a_failed_read_of_the_log_is_tried_again_and_the_session_goes_on(
    watched: tuple[Printer, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    printer, key = watched
    failures: dict[str, list[int]] = {}

    async def scenario() -> list[str]:
        server, reader, writer, _ = await open_session(printer, key)
        failures["left"] = fail_log_reads(monkeypatch, 2)
        await database_sync_to_async(add_lines)(printer, 1, 2)
        got = [
            (await asyncio.wait_for(reader.readline(), 10)).decode() for _ in range(2)
        ]
        writer.close()
        server.close()
        return got

    assert asyncio.run(asyncio.wait_for(scenario(), 30)) == ["echo 1\n", "echo 2\n"]
    assert failures["left"] == [0], "the reads did not fail"
