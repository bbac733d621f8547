"""What the live-feed tests share: a printer, no relays, a quick reconcile, counted
log reads, lines in the log and batches of them published."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import pytest
from channels.db import database_sync_to_async
from channels.layers import channel_layers
from django.utils import timezone

from printers import broadcast, live
from printers.models import Printer, ResponseLine


@pytest.fixture
def printer(make_printer: Callable[..., Printer]) -> Printer:
    return make_printer(slug="mk3", state="idle")


@pytest.fixture
def quiet_feed(monkeypatch: pytest.MonkeyPatch) -> None:
    """No relay publishes (only the test does, or nobody: every live message is
    'lost'), and clients reconcile with the log every 0.2 s."""

    async def no_relay(printer_id: int) -> None:
        """Nothing watches the printer's log for the test's clients."""

    monkeypatch.setattr(broadcast, "watch", no_relay)
    monkeypatch.setattr(broadcast, "unwatch", no_relay)
    monkeypatch.setattr(live, "RECONCILE_SECONDS", 0.2)


@pytest.fixture
def log_reads(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The cursor of each read of the response log by a client (live.lines_after)."""
    reads: list[int] = []
    read = live.lines_after

    def counted(printer_id: int, last: int, upto: int | None = None) -> list:
        reads.append(last)
        return read(printer_id, last, upto)

    monkeypatch.setattr(live, "lines_after", counted)
    return reads


def add_lines(printer: Printer, first: int, last: int, kind: int = 4) -> None:
    """Lines `echo <seq>` for seq first..last in the printer's response log."""
    ResponseLine.objects.bulk_create(
        ResponseLine(
            printer=printer, seq=i, time=timezone.now(), text=f"echo {i}", kind=kind
        )
        for i in range(first, last + 1)
    )


async def batches_then_a_lost_one(printer: Printer, reads: list[int]) -> int:
    """Lines 1-20 logged and published a batch each 0.05 s (five reconcile periods of
    quiet_feed), then 21-22 logged only (their batch lost); returns how many log
    reads (log_reads) the client made while the batches came."""
    reads.clear()
    layer = channel_layers["default"]
    for seq in range(1, 21):
        await database_sync_to_async(add_lines)(printer, seq, seq)
        line = live.line_dict(seq, timezone.now(), f"echo {seq}", 4)
        await layer.group_send(
            live.group_for(printer.pk),
            {"type": "live.event", "printer_id": printer.pk,
             "event": {"type": "lines", "lines": [line]}},
        )  # fmt: skip
        await asyncio.sleep(0.05)
    while_heard = len(reads)
    await database_sync_to_async(add_lines)(printer, 21, 22)
    return while_heard


def fail_log_reads(monkeypatch: pytest.MonkeyPatch, times: int) -> list[int]:
    """Make the next *times* reads of the response log (live.lines_after) raise as
    a locked database does; returns [how many are still to fail]."""
    from django.db import OperationalError

    read, failures = live.lines_after, [times]

    def flaky(printer_id: int, last: int, upto: int | None = None) -> list:
        if failures[0]:
            failures[0] -= 1
            raise OperationalError("database is locked")
        return read(printer_id, last, upto)

    monkeypatch.setattr(live, "lines_after", flaky)
    return failures
