"""Temperature history: the worker's samples (at most every 5 s) and the endpoint (their
retention: tests/upkeep/test_upkeep_temperature_samples.py)."""

from __future__ import annotations

from datetime import timedelta
from typing import TYPE_CHECKING, Any

from django.contrib.auth import get_user_model
from django.utils import timezone

from printers.models import TemperatureSample
from printers.worker.status import PrinterStatus
from printhost.models import PrinterRole, Role

if TYPE_CHECKING:
    from collections.abc import Callable

    from django.test import Client

    from printers.models import Printer

HOT = {"T0": {"current": 200.0, "target": 210.0}}


def viewer(printer: Printer) -> Any:
    user = get_user_model().objects.create_user("v", password="v")
    PrinterRole.objects.create(user=user, printer=printer, role=Role.VIEWER)
    return user


def test_worker_writes_a_sample_at_most_every_5_seconds(
    make_printer: Callable[..., Printer],
) -> None:
    printer = make_printer()
    status = PrinterStatus(printer.pk)
    for now in (100.0, 101.0, 102.0, 104.9, 105.0, 106.0, 110.1):
        status.update(temperatures={"T0": {"current": now, "target": 0}})
        status.save_if_due(now, force=True)
    kept = [
        s.temperatures["T0"]["current"]
        for s in TemperatureSample.objects.filter(printer=printer).order_by("time")
    ]
    assert kept == [100.0, 105.0, 110.1]


def test_endpoint_returns_samples_in_order_within_the_window(
    client: Client, make_printer: Callable[..., Printer]
) -> None:
    printer = make_printer()
    now = timezone.now()
    for minutes in (45, 20, 5, 10):
        TemperatureSample.objects.create(
            printer=printer,
            time=now - timedelta(minutes=minutes),
            temperatures={"B": {"current": minutes, "target": 60}},
        )
    client.force_login(viewer(printer))
    body = client.get(f"/printer/temperatures/{printer.slug}").json()
    assert body["error"] == ""
    assert [s["temperatures"]["B"]["current"] for s in body["data"]] == [20, 10, 5]
    wide = client.get(f"/printer/temperatures/{printer.slug}?minutes=60").json()
    assert len(wide["data"]) == 4


def test_endpoint_refuses_garbage_and_too_long_windows(
    client: Client, make_printer: Callable[..., Printer]
) -> None:
    printer = make_printer()
    client.force_login(viewer(printer))
    for value in ("abc", "0", "-5", "1441"):
        response = client.get(f"/printer/temperatures/{printer.slug}?minutes={value}")
        assert response.status_code == 400, value
        assert "minutes" in response.json()["error"]
    assert (
        client.get(f"/printer/temperatures/{printer.slug}?minutes=1440").status_code
        == 200
    )
