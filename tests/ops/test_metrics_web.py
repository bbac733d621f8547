"""Web request latency: one histogram summed over every daphne process's file."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from prometheus_client.multiprocess import MultiProcessCollector

from printhost import metrics_web

COUNT = "printhost_http_request_duration_seconds_count"

#: Another process adding to the histogram, as a daphne process does: the real
#: module, its folder from PRINTHOST_METRICS_DIR.
OTHER_PROCESS = """
import sys
from printhost.metrics_web import REQUEST_SECONDS
for seconds in sys.argv[1:]:
    REQUEST_SECONDS.labels("GET", "/api/version", "2xx").observe(float(seconds))
"""


def other_process(folder: Path, *seconds: float) -> None:
    """Run a process that records *seconds* in *folder*'s files, then ends."""
    env = {**os.environ, "PRINTHOST_METRICS_DIR": str(folder),
           "DJANGO_SETTINGS_MODULE": "printhost.settings"}  # fmt: skip
    subprocess.run(
        [sys.executable, "-c", OTHER_PROCESS, *map(str, seconds)],
        env=env, check=True, timeout=60, cwd=Path(__file__).parents[2],
    )  # fmt: skip


def counts(folder: Path) -> dict:
    """{(route, le or ""): value} of the histogram summed over *folder*'s files."""
    found = {}
    for family in MultiProcessCollector(None, path=str(folder)).collect():
        for sample in family.samples:
            key = (sample.name.rsplit("_", 1)[1], sample.labels.get("le", ""))
            found[key] = sample.value
    return found


def test_requests_are_counted_by_route_and_status(db, client):
    def scraped() -> dict:
        return {
            (sample.name, frozenset(sample.labels.items())): sample.value
            for family in metrics_web.WebCollector().collect()
            for sample in family.samples
        }

    version = (
        COUNT,
        frozenset({"method": "GET", "route": "/api/version", "status": "2xx"}.items()),
    )
    missing = (
        COUNT,
        frozenset({"method": "GET", "route": "unmatched", "status": "4xx"}.items()),
    )
    before = scraped()
    client.get("/api/version")
    client.get("/api/version")
    client.get("/no/such/page/")
    after = scraped()
    assert after[version] - before.get(version, 0) == 2
    assert after[missing] - before.get(missing, 0) == 1


def test_the_scrape_exports_the_histogram_with_buckets(db, client, scrape):
    client.get("/api/version")
    found = scrape()
    buckets = [
        dict(labels)["le"]
        for name, labels in found
        if name == "printhost_http_request_duration_seconds_bucket"
        and dict(labels)["route"] == "/api/version"
    ]
    assert "+Inf" in buckets
    assert "0.1" in buckets


def test_ended_processes_are_folded_into_the_archive_and_keep_their_counts(tmp_path):
    other_process(tmp_path, 0.003, 0.2)
    other_process(tmp_path, 0.2)
    assert len(list(tmp_path.glob("histogram_*.db"))) == 2
    before = counts(tmp_path)
    assert before[("count", "")] == 3

    assert metrics_web.compact(tmp_path) == 2
    assert [p.name for p in tmp_path.glob("*.db")] == [metrics_web.ARCHIVE]
    assert counts(tmp_path) == before

    other_process(tmp_path, 5.0)
    assert metrics_web.compact(tmp_path) == 1
    after = counts(tmp_path)
    assert after[("count", "")] == 4
    assert after[("bucket", "0.005")] == 1
    assert after[("bucket", "0.25")] == 3
    assert after[("bucket", "+Inf")] == 4
    assert after[("sum", "")] == pytest.approx(5.403)


def test_a_live_processs_file_is_not_folded(tmp_path):
    other_process(tmp_path, 0.1)
    mine = tmp_path / f"histogram_{os.getpid()}.db"
    (tmp_path / next(tmp_path.glob("histogram_*.db")).name).rename(mine)
    assert metrics_web.compact(tmp_path) == 0
    assert mine.exists()
