"""bench.farm's figures: each job's slowdown, each worker's CPU, the server's latency
from /metrics, and the farm's checks (what bench/farm.py measures, not how it runs)."""

from __future__ import annotations

import statistics
import time
from typing import TYPE_CHECKING, Any

from tests.farmrig import checks
from tests.farmrig.processes import cpu_seconds

if TYPE_CHECKING:
    from tests.farmrig.rig import Farm

#: The routes the API load asks (server-side latency is read for these).
LOAD_ROUTES = ("/printer/state/<slug>", "/printer/list", "/printer/farm")


def rounded(value: float | None, digits: int) -> float | None:
    return None if value is None else round(value, digits)


def p95(values: list[float]) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(0.95 * len(ordered)))]


def load_latency(text: str) -> dict[str, Any]:
    """Median and p95 (bucket bounds) of the load's GETs in a /metrics text."""
    from prometheus_client.parser import text_string_to_metric_families

    buckets: dict[float, float] = {}
    for family in text_string_to_metric_families(text):
        if family.name != "printhost_http_request_duration_seconds":
            continue
        for sample in family.samples:
            labels = sample.labels
            if (
                sample.name.endswith("_bucket")
                and labels.get("method") == "GET"
                and labels.get("route") in LOAD_ROUTES
            ):
                bound = float(labels["le"])
                buckets[bound] = buckets.get(bound, 0.0) + sample.value
    total = buckets.get(float("inf"), 0.0)
    if not total:
        return {"requests": 0}

    def at_most(share: float) -> float:
        return next(b for b in sorted(buckets) if buckets[b] >= share * total)

    return {
        "requests": int(total),
        "median_at_most_ms": at_most(0.5) * 1000,
        "p95_at_most_ms": at_most(0.95) * 1000,
    }


def run_checks(farm: Farm) -> dict[str, str]:
    results = {}
    for name, check in (
        ("ran once", checks.jobs_ran_once),
        ("matching printers", checks.matching_printers),
        ("records match", checks.records_match),
    ):
        try:
            check(farm)
            results[name] = "ok"
        except AssertionError as error:
            results[name] = f"failed: {error}"
    return results


def job_figures(farm: Farm, base: dict[str, float]) -> list[dict]:
    """Each farm job: its file, printer, time, slowdown against the baseline, and the
    most printers printing at once while it ran."""
    rows = farm.query(
        "SELECT f.id, p.slug, j.started_at, j.finished_at, j.state FROM jobs_farmjob f "
        "JOIN jobs_job j ON j.id = f.job_id JOIN printers_printer p ON p.id = j.printer_id"
    )
    spans = [(r[2], r[3]) for r in rows if r[2] and r[3]]
    out = []
    for farm_job, slug, start, end, state in rows:
        if not (start and end):
            continue
        file = farm.uploaded[farm_job].file
        seconds = (end - start).total_seconds()
        out.append(
            {
                "farm_job": farm_job, "file": file, "printer": slug, "state": state,
                "seconds": round(seconds, 2),
                "slowdown": round(seconds / base[file] - 1, 4),
                "concurrent": most_at_once(start, end, spans),
            }
        )  # fmt: skip
    return out


def most_at_once(start: object, end: object, spans: list[tuple]) -> int:
    """The most of *spans* (start, end) running at one moment within [start, end]."""
    points = [start, *(s for s, _ in spans if start <= s < end)]
    return max(sum(1 for s, e in spans if s <= point < e) for point in points)


class CpuWatch:
    """Each run_printer's CPU seconds and lines acked from the farm's start on."""

    def __init__(self, farm: Farm) -> None:
        self.farm = farm
        self.first: dict[str, tuple[int, float, float]] = {}
        self.last: dict[str, tuple[int, float, float]] = {}
        self.lines_at_start = self._lines()
        self._next = 0.0

    def _lines(self) -> dict[str, int]:
        rows = self.farm.query(
            "SELECT p.slug, COALESCE(SUM(j.lines_acked), 0) FROM printers_printer p "
            "LEFT JOIN jobs_job j ON j.printer_id = p.id GROUP BY p.slug"
        )
        return {slug: int(n) for slug, n in rows}

    def sample(self) -> None:
        now = time.monotonic()
        if now < self._next:
            return
        self._next = now + 1.0
        for runhost in self.farm.runhosts.values():
            for slug, pid in runhost.workers().items():
                used = cpu_seconds(pid)
                if used is None:
                    continue
                if slug not in self.first or self.first[slug][0] != pid:
                    self.first[slug] = (pid, used, now)
                self.last[slug] = (pid, used, now)

    def figures(self) -> dict[str, Any]:
        lines = self._lines()
        per = {}
        for slug, (_pid, used, at) in self.last.items():
            _first_pid, first_used, first_at = self.first[slug]
            wall = at - first_at
            done = lines.get(slug, 0) - self.lines_at_start.get(slug, 0)
            cpu = used - first_used
            per[slug] = {
                "cpu_share": round(cpu / wall, 4) if wall > 0 else None,
                "cpu_s_per_1k_lines": round(cpu / done * 1000, 4) if done else None,
                "lines": done,
            }
        shares = [v["cpu_share"] for v in per.values() if v["cpu_share"] is not None]
        per_k = [
            v["cpu_s_per_1k_lines"]
            for v in per.values()
            if v["cpu_s_per_1k_lines"] is not None
        ]
        return {
            "per_printer": per,
            "cpu_share_mean": round(statistics.mean(shares), 4) if shares else None,
            "cpu_share_total": round(sum(shares), 3) if shares else None,
            "cpu_s_per_1k_lines_median": round(statistics.median(per_k), 4)
            if per_k
            else None,
        }
