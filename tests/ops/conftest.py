"""Fixtures of the ops tests: a small farm in the database and a parsed scrape."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import timedelta
from typing import TYPE_CHECKING

import pytest
from django.utils import timezone
from prometheus_client.parser import text_string_to_metric_families

from jobs.models import Job
from printers.hosts import WorkerHost
from printers.models import Printer
from printhost.metrics_web import REQUEST_SECONDS

if TYPE_CHECKING:
    from collections.abc import Callable

    from django.test import Client


@dataclass
class Farm:
    rack: WorkerHost
    idle: Printer
    busy: Printer
    job: Job


def samples(text: str) -> dict[tuple[str, frozenset], float]:
    """{(sample name, labels): value} of a Prometheus text exposition."""
    found = {}
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            found[(sample.name, frozenset(sample.labels.items()))] = sample.value
    return found


def value(found: dict, name: str, **labels: str) -> float:
    return found[(name, frozenset(labels.items()))]


@pytest.fixture
def no_latency_history(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    """Scrapes read an empty latency folder. The suite's own requests (every route,
    every status) fill this process's histogram, and summing thousands of series
    costs a second a scrape; the tests that use this do not check latency."""
    # This process's file opens where it belongs before scrapes look elsewhere.
    REQUEST_SECONDS.labels("GET", "unmatched", "4xx")
    monkeypatch.setenv("PROMETHEUS_MULTIPROC_DIR", str(tmp_path / "latency"))


@pytest.fixture
def scrape(client: Client, django_user_model: type) -> Callable[..., dict]:
    """GET /metrics as a superuser's session; the samples, parsed."""
    admin = django_user_model.objects.create_user("root", is_superuser=True)
    client.force_login(admin)

    def get() -> dict:
        response = client.get("/metrics")
        assert response.status_code == 200, response.content
        return samples(response.content.decode())

    return get


@pytest.fixture
def farm(make_printer: Callable[..., Printer], make_job: Callable[..., Job]) -> Farm:
    """A worker host with two printers: one idle, one printing a job half done."""
    now = timezone.now()
    rack = WorkerHost.objects.create(
        name="rack1",
        version="0.1.0",
        hostname="pi-rack1",
        seen_at=now - timedelta(seconds=4),
        load={"loadavg": [0.5, 0.25, 0.125], "cpus": 4, "memory_free_mb": 512,
              "disk_free_mb": 2048, "clock_offset_s": -3.5},
        printers={"mk4": {"pid": 10, "running": True, "restarts": 2},
                  "voron": {"pid": 11, "running": False, "restarts": 1}},
    )  # fmt: skip
    idle = make_printer(slug="voron", state=Printer.State.IDLE, worker_host=rack)
    busy = make_printer(
        slug="mk4",
        state=Printer.State.PRINTING,
        worker_host=rack,
        firmware="marlin",
        material="PLA",
        temperatures={"T0": {"current": 214.5, "target": 215}, "B": {"current": 60.2, "target": 60}},
        link_stats={
            "at": now.isoformat(), "connected_at": (now - timedelta(hours=1)).isoformat(),
            "lines_sent": 20000, "lines_acked": 19990, "resends": 30, "timeouts": 4,
            "bytes_sent": 500000, "bytes_received": 90000, "rtt_ms": 12.5,
            "lines_per_s": 180.0, "link_use": 0.85, "cpu_s": 42.0,
        },
    )  # fmt: skip
    job = make_job(busy, "G28\n" + "G1 X1\nG1 X2\n" * 50)
    Job.objects.filter(pk=job.pk).update(
        state=Job.State.PRINTING,
        lines_acked=25,
        bytes_acked=job.size_bytes // 4,
    )
    job.refresh_from_db()
    return Farm(rack=rack, idle=idle, busy=busy, job=job)
