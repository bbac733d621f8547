"""bench.farm's verdicts and summary: the figures of a run held against issue 11's
goals (PASS/FAIL lines) and printed as a few rows."""

from __future__ import annotations

import statistics
from pathlib import Path

#: Issue 11's goals.
PRINTERS_GOAL = 32
SLOWDOWN_GOAL = 0.02
CPU_PER_1K_GOAL = 0.1


def capacity_line(capacity: dict) -> str:
    slow = [j["slowdown"] for j in capacity["jobs"]]
    return (
        f"{len(slow)} jobs, most at once "
        f"{max((j['concurrent'] for j in capacity['jobs']), default=0)}, slowdown "
        f"median {_pct(statistics.median(slow) if slow else None)}, worst "
        f"{_pct(max(slow) if slow else None)}; cores {capacity['cpu_cores']}"
    )


def driven_within(jobs: list[dict], goal: float = SLOWDOWN_GOAL) -> int:
    """The most printers printing at once such that every job that ran with at most
    that many printers finished within *goal* of its single-printer time."""
    best = 0
    for level in sorted({j["concurrent"] for j in jobs}):
        if all(j["slowdown"] <= goal for j in jobs if j["concurrent"] <= level):
            best = level
        else:
            break
    return best


def judge(report: dict) -> list[str]:
    if "error" in report:
        return [f"FAIL the farm did not run: {report['error'].splitlines()[-1]}"]
    lines = []
    for name, result in report["checks"].items():
        lines.append(
            f"{'PASS' if result == 'ok' else 'FAIL'} farm: {name}: {result[:300]}"
        )
    jobs = report["jobs"]
    capacity = report.get("capacity", {}).get("jobs", [])
    driven = driven_within(capacity)
    lines.append(
        f"{'PASS' if driven >= PRINTERS_GOAL else 'FAIL'} printers one 2-core machine "
        f"drives with every job within {SLOWDOWN_GOAL:.0%} of its single-printer "
        f"time: {driven} >= {PRINTERS_GOAL} (the control plane, PostgreSQL, Redis "
        f"and the simulators on the same cores; worst "
        f"{_pct(max((j['slowdown'] for j in capacity), default=None))})"
    )
    slow = [j["slowdown"] for j in jobs]
    worst = max(slow) if slow else None
    web = report["web"]
    lines.append(
        f"{'PASS' if worst is not None and worst < SLOWDOWN_GOAL else 'FAIL'} stream "
        f"slowdown with {web['clients']} websocket clients and "
        f"{web['api_rate']:g} API requests/s ({rate_reached(web)}): worst "
        f"{_pct(worst)}, median {_pct(statistics.median(slow) if slow else None)} "
        f"< {SLOWDOWN_GOAL:.0%}"
    )
    lines.append(
        f"INFO web p95 latency {web['api_p95_ms']} ms as the clients saw it once sent "
        f"({web['api_errors']} errors; the clients' own lag p95 "
        f"{web.get('client_lag_p95_ms')} ms); in Django: {web.get('server')}"
    )
    workers = report["workers"]
    lines.append(
        f"INFO worker CPU per printer while printing: "
        f"{_pct(workers['cpu_share_mean'])} of a core on average, "
        f"{workers['cpu_s_per_1k_lines_median']} s per 1,000 lines at these prints' "
        f"line rate (the {CPU_PER_1K_GOAL} s goal at 250000 baud is bench.streaming's)"
    )
    for name, result in report.get("faults", {}).items():
        lines.append(f"{'PASS' if result.startswith('ok') else 'FAIL'} fault: {name}: "
                     f"{result[:300]}")  # fmt: skip
    return lines


def rate_reached(web: dict) -> str:
    """The API load's real rate: requests sent over the seconds it ran. Issued on
    schedule but not sent means the server's answers held its connections."""
    achieved = web.get("api_rate_achieved")
    if achieved is None:
        return "rate reached unknown"
    return (
        f"{achieved:g}/s reached: {web.get('api_sent')} sent of "
        f"{web.get('api_issued')} issued on schedule"
    )


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{value:+.2%}"


def summary(report: dict) -> str:
    if "error" in report:
        return "farm: did not run"
    workers = report["workers"]
    jobs = report["jobs"]
    rows = [
        f"farm: {report['config']['printers']} printers, {report['config']['hosts']} "
        f"worker hosts, {len(jobs)} jobs in {report['farm_seconds']} s at time scale "
        f"{report['config']['time_scale']:g}",
        "baseline (one printer alone): "
        + ", ".join(f"{Path(f).stem} {s:.1f} s" for f, s in report["baseline"].items()),
        f"capacity (one job per printer at once, no web load): "
        f"{capacity_line(report['capacity'])}",
        f"most printers printing at once: {max((j['concurrent'] for j in jobs), default=0)}",
        *slowdown_rows(jobs),
        f"worker CPU per printer: mean {_pct(workers['cpu_share_mean'])} of a core, "
        f"all workers {workers['cpu_share_total']} cores; per 1,000 lines (median) "
        f"{workers['cpu_s_per_1k_lines_median']} s",
        f"web: {report['web']}",
        f"cores used during the farm phase: {report['cpu_cores']}",
    ]
    return "\n".join(rows)


def slowdown_rows(jobs: list[dict]) -> list[str]:
    """Slowdown against the baseline by how many printers were printing meanwhile."""
    rows = []
    for low, high in ((1, 8), (9, 16), (17, 24), (25, 32), (33, 10**6)):
        these = [j["slowdown"] for j in jobs if low <= j["concurrent"] <= high]
        if these:
            rows.append(
                f"  {low}-{high if high < 10**6 else ''} printing at once: "
                f"{len(these)} jobs, slowdown median {_pct(statistics.median(these))}, "
                f"worst {_pct(max(these))}"
            )
    return rows
