"""Upkeep: temperature samples older than PRINTHOST_TEMPERATURE_KEEP_HOURS (24 h) are
deleted by beat, and the printer's worker no longer deletes them in its loop."""

from __future__ import annotations

from datetime import timedelta
from typing import TYPE_CHECKING

import pytest
from django.utils import timezone

from printers.models import TemperatureSample
from printers.upkeep import prune_temperature_samples
from printers.worker.status import PrinterStatus

if TYPE_CHECKING:
    from collections.abc import Callable
    from datetime import datetime

    from printers.models import Printer

pytestmark = pytest.mark.django_db

HOT = {"T0": {"current": 200.0, "target": 210.0}}


def sample(printer: Printer, at: datetime) -> int:
    return TemperatureSample.objects.create(
        printer=printer, time=at, temperatures=HOT
    ).pk


def test_samples_older_than_a_day_go_and_a_day_old_ones_stay(
    make_printer: Callable[..., Printer],
) -> None:
    now = timezone.now()
    first, second = make_printer(), make_printer()
    old = [
        sample(first, now - timedelta(hours=25)),
        sample(first, now - timedelta(hours=24, microseconds=1)),
        sample(second, now - timedelta(days=3)),
    ]
    young = [
        sample(first, now - timedelta(hours=24)),  # exactly the limit
        sample(first, now - timedelta(hours=1)),
        sample(second, now),
    ]

    assert prune_temperature_samples(now=now, batch=2) == {"samples": 3}

    remaining = set(TemperatureSample.objects.values_list("pk", flat=True))
    assert remaining == set(young)
    assert not remaining & set(old)


def test_the_retention_is_a_setting(
    make_printer: Callable[..., Printer], settings: object
) -> None:
    settings.PRINTHOST_TEMPERATURE_KEEP_HOURS = 2  # type: ignore[attr-defined]
    now = timezone.now()
    printer = make_printer()
    gone = sample(printer, now - timedelta(hours=3))
    stays = sample(printer, now - timedelta(hours=1))
    assert prune_temperature_samples(now=now) == {"samples": 1}
    assert list(TemperatureSample.objects.values_list("pk", flat=True)) == [stays]
    assert gone != stays


def test_many_samples_go_in_batches_and_none_of_the_last_day(
    make_printer: Callable[..., Printer],
) -> None:
    now = timezone.now()
    printer = make_printer()
    TemperatureSample.objects.bulk_create(
        TemperatureSample(
            printer=printer, time=now - timedelta(hours=24, minutes=m), temperatures=HOT
        )
        for m in range(-30, 60)  # 30 younger than a day, one exactly, 59 older
    )
    assert prune_temperature_samples(now=now, batch=7) == {"samples": 59}
    assert TemperatureSample.objects.count() == 31


def test_the_worker_writes_samples_and_deletes_none(
    make_printer: Callable[..., Printer],
) -> None:
    printer = make_printer()
    old = sample(printer, timezone.now() - timedelta(hours=25))
    status = PrinterStatus(printer.pk)
    assert status.sample(0.0, HOT)
    assert status.sample(700.0, HOT)  # the old loop pruned every 600 s
    assert TemperatureSample.objects.filter(pk=old).exists()
    assert TemperatureSample.objects.filter(printer=printer).count() == 3
