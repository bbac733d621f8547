"""Temperature history: what the printer page's chart draws before live points arrive."""

from __future__ import annotations

from datetime import timedelta

from django.http import HttpRequest, JsonResponse  # noqa: TC002 (ninja reads view hints)
from django.utils import timezone
from ninja import Router
from ninja.errors import HttpError

from printers.models import TemperatureSample
from printhost.api.common import envelope, parse_int, printer_for
from printhost.models import Role

router = Router(tags=["printer (host extras)"])

#: The longest history one call returns: the worker keeps a day of samples.
MAX_MINUTES = 24 * 60


@router.get("/printer/temperatures/{slug}", summary="Temperature history")
def temperatures(request: HttpRequest, slug: str) -> JsonResponse:
    """Samples of the last `minutes` (default 30, at most 1440), oldest first.

    Each is `{"time": iso, "temperatures": {"T0": {"current", "target"}, ...}}`.
    """
    printer = printer_for(request, slug, Role.VIEWER)
    minutes = parse_int(request.GET.get("minutes"), "minutes", default=30, minimum=1)
    if minutes > MAX_MINUTES:
        raise HttpError(400, f"minutes must be at most {MAX_MINUTES}, not {minutes}")
    since = timezone.now() - timedelta(minutes=minutes)
    rows = (
        TemperatureSample.objects.filter(printer=printer, time__gte=since)
        .order_by("time")
        .values_list("time", "temperatures")
    )
    return envelope(
        [{"time": when.isoformat(), "temperatures": temps} for when, temps in rows]
    )
