"""Fixtures of the worker-host tests: this computer's clock put off the database's.

`timezone.now()` and `time.time()` are shifted in this process (a board without a
battery-backed clock after a power cut, or a web server on a computer of its own);
the database (SQLite, in-process) keeps the true time. The offset this process
learned is put back afterwards.
"""

from __future__ import annotations

import time
from datetime import timedelta
from typing import TYPE_CHECKING
from unittest import mock

import pytest
from django.utils import timezone

from printers import dbclock

if TYPE_CHECKING:
    from collections.abc import Iterator

HOUR = 3600.0


def _clock_off(monkeypatch: pytest.MonkeyPatch, seconds: float) -> Iterator[None]:
    """This computer's clock *seconds* ahead of the database's (behind: < 0), its
    offset not learned yet (the root conftest takes it as just read)."""
    monkeypatch.setattr(dbclock, "_offset", 0.0)
    monkeypatch.setattr(dbclock, "_learned_at", float("-inf"))
    real_now, real_time = timezone.now, time.time
    with (
        mock.patch(
            "django.utils.timezone.now", lambda: real_now() + timedelta(seconds=seconds)
        ),
        mock.patch("time.time", lambda: real_time() + seconds),
    ):
        yield


@pytest.fixture
def hour_behind(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    yield from _clock_off(monkeypatch, -HOUR)


@pytest.fixture
def hour_ahead(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    yield from _clock_off(monkeypatch, HOUR)
