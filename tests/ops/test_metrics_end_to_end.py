"""/metrics of a real runhost, and a worker host's serve_metrics, over HTTP.

One installation: runhost drives a simulated printer (c1) and serves /metrics
behind a scrape token; a worker host (rack1) has a printer whose worker would run
on the host (its link figures written here as that worker writes them), served by
`manage.py serve_metrics --worker-host rack1`. Logs are JSON (PRINTHOST_LOG_FORMAT).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path

import httpx
import pytest

from tests.conftest import ROOT, wait_for
from tests.hosts import Host, free_port
from tests.ops.conftest import samples, value

pytestmark = pytest.mark.slow

TOKEN = "e2e-scrape-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
STATS = {"lines_sent": 4000, "lines_acked": 3990, "resends": 8, "timeouts": 1,
         "bytes_sent": 96000, "bytes_received": 20000, "rtt_ms": 7.0,
         "lines_per_s": 150.0, "link_use": 0.6, "cpu_s": 3.5}  # fmt: skip


def get(url: str, headers: dict | None = None) -> httpx.Response:
    return httpx.get(url, headers=headers or {}, timeout=10)


@pytest.fixture
def host(tmp_path: Path) -> Host:
    host = Host(tmp_path)
    host.env |= {"PRINTHOST_METRICS_TOKEN": TOKEN, "PRINTHOST_LOG_FORMAT": "json"}
    host.migrate()
    host.add_simulated_printer("c1")
    stats = {**STATS, "at": datetime.now(UTC).isoformat()}
    host.shell(
        "from printers.models import Printer; from printers.hosts import WorkerHost; "
        "Printer.objects.create(name='R1', slug='r1', port='/dev/null', state='printing', "
        "worker_host=WorkerHost.objects.create(name='rack1'), "
        f"link_stats={stats!r})"
    )
    return host


def test_runhost_and_a_worker_host_serve_parsed_metrics(host: Host):
    with host.running():
        metrics = f"{host.url}/metrics"
        assert get(metrics).status_code == 401
        idle = {"printer": "c1", "host": "_control", "state": "idle"}

        def c1_idle() -> bool:
            found = samples(get(metrics, AUTH).text)
            return found.get(("printhost_printer_state", frozenset(idle.items()))) == 1

        wait_for(c1_idle, 30, "c1's worker to report idle on /metrics")
        found = samples(get(metrics, AUTH).text)
        r1 = {"printer": "r1", "host": "rack1"}
        assert value(found, "printhost_printer_state", **r1, state="printing") == 1
        assert value(found, "printhost_printer_lines_per_second", **r1) == 150.0
        assert value(found, "printhost_printer_resends_per_1000_lines", **r1) == 2.0
        assert value(found, "printhost_host_up", host="rack1") == 0
        assert value(found, "printhost_celery_broker_up") == 1
        assert value(found, "printhost_celery_queue_length", queue="printhost") >= 0
        route = {"method": "GET", "route": "/metrics", "status": "2xx"}
        assert (
            value(found, "printhost_http_request_duration_seconds_count", **route) >= 1
        )

        served = serve_metrics(host, "rack1")
        try:
            url = served.url
            assert get(url).status_code == 401
            assert get(url, {"Authorization": "Bearer nope"}).status_code == 401
            found = samples(get(url, AUTH).text)
        finally:
            served.stop()
        printers = {
            dict(k[1])["printer"] for k in found if k[0] == "printhost_printer_state"
        }
        assert printers == {"r1"}
        assert (
            value(found, "printhost_printer_link_use_ratio", printer="r1", host="rack1")
            == 0.6
        )
        assert host.query("SELECT metrics_address FROM printers_workerhost") == [
            (served.address,)
        ]
    assert_json_logs(host.folder / "runhost.log")


class Served:
    """A running `serve_metrics`."""

    def __init__(self, process: subprocess.Popen, address: str) -> None:
        self.process = process
        self.address = address
        self.url = f"http://{address}/metrics"

    def stop(self) -> None:
        self.process.send_signal(signal.SIGTERM)
        assert self.process.wait(timeout=10) == 0


def serve_metrics(host: Host, name: str) -> Served:
    port = free_port()
    process = subprocess.Popen(
        [sys.executable, "manage.py", "serve_metrics", "--worker-host", name,
         "--port", str(port)],
        cwd=ROOT, env=host.env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
    )  # fmt: skip
    line = process.stdout.readline().decode()
    assert "/metrics" in line, line + process.stdout.read().decode()
    return Served(process, f"127.0.0.1:{port}")


def assert_json_logs(path: Path) -> None:
    """Every log record in runhost's output (its own, daphne's and its access log,
    the workers') is one JSON object; the other lines are the commands' own prints
    (runhost's address, the simulator's ready line)."""
    records, prints = [], []
    for line in path.read_text().splitlines():
        parsed = json.loads(line) if line.startswith("{") else {}
        if "logger" in parsed:
            records.append(parsed)
        elif not parsed.get("ready"):
            prints.append(line)
    assert all(line.startswith("printhost ") for line in prints), prints
    assert all({"time", "level", "message", "pid"} <= set(r) for r in records)
    loggers = {record["logger"] for record in records}
    assert {"printhost.runhost", "daphne.server", "printhost.access"} <= loggers
    access = [r for r in records if r["logger"] == "printhost.access"]
    assert {"path": "/metrics", "status": 401, "method": "GET"}.items() <= access[
        0
    ].items()
