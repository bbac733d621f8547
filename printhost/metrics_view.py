"""`/metrics`: the control plane's Prometheus endpoint, and what each scrape collects.

The control plane's answer holds every printer and worker host (printhost/metrics.py),
the web request latency of this computer's daphne processes (metrics_web.py) and the
Celery queue lengths (metrics_queues.py). A worker host's `serve_metrics` answers
with `scrape(host=NAME)`: its printers and its own row only (no web server, no
Celery there). The view checks the caller (metrics_access.py), then reads.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from django.http import HttpResponse, JsonResponse
from django.views.decorators.http import require_safe
from prometheus_client import CollectorRegistry
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.exposition import choose_encoder

from printhost.metrics import FarmCollector
from printhost.metrics_access import Refusal, request_refusal
from printhost.metrics_queues import queue_families
from printhost.metrics_web import WebCollector

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Iterator

    from django.http import HttpRequest
    from prometheus_client import Metric


class _Families:
    """A collector made of a function that yields metric families."""

    def __init__(self, families: Callable[[], Iterable[Metric]]) -> None:
        self.families = families

    def collect(self) -> Iterable[Metric]:
        return self.families()


def scrape(accept: str = "", host: str | None = None) -> tuple[bytes, str]:
    """The exposition (body, content type) of the control plane, or of worker *host*."""
    started = time.perf_counter()
    registry = CollectorRegistry(auto_describe=False)
    registry.register(FarmCollector(host))
    if host is None:
        registry.register(WebCollector())
        registry.register(_Families(queue_families))
    # Collected last (a registry keeps its collectors in order): it times the rest.
    registry.register(_Families(lambda: _scrape_seconds(time.perf_counter() - started)))
    encoder, content_type = choose_encoder(accept)
    return encoder(registry), content_type


def _scrape_seconds(seconds: float) -> Iterator[Metric]:
    yield GaugeMetricFamily(
        "printhost_metrics_scrape_seconds",
        "Time this answer took to read the database and the broker",
        value=seconds,
    )


def refused(refusal: Refusal) -> HttpResponse:
    response = JsonResponse({"error": refusal.message}, status=refusal.status)
    if refusal.status == 401:
        response["WWW-Authenticate"] = 'Bearer realm="printhost metrics"'
    return response


@require_safe
def metrics(request: HttpRequest) -> HttpResponse:
    """GET /metrics: the Prometheus text format, for the token or an admin."""
    refusal = request_refusal(request)
    if refusal is not None:
        return refused(refusal)
    body, content_type = scrape(request.headers.get("Accept", ""))
    return HttpResponse(body, content_type=content_type)
