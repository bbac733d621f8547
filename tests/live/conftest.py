"""What the live-feed tests share: no relays, a quick reconcile, counted log reads."""

from __future__ import annotations

import pytest

from printers import broadcast, live


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
