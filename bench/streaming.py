"""`make bench`: stream generated files through the simulators over ptys and report.

Cases: Marlin ping-pong, Marlin windowed (ADVANCED_OK, and the byte budget without
it) and GRBL character counting; 115200 and 250000 baud with 0, 4 and 16 ms latency
each way, and unthrottled; then 8 printers at once at 250000. Each case runs in its
own process (bench/case.py), one after another, so they do not share the CPU.
Each case of the CPU goal (250000 baud, no latency) runs CPU_RUNS times in turns
with the reference host (bench/reference_host.py, the least any Python host does a
line); each side keeps its run of least CPU, and the worker's CPU per 1,000 lines is
printed beside the reference's.
Writes bench-results.json and prints a table plus the checks of the targets.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from bench import soak

ROOT = Path(__file__).resolve().parent.parent
MODES = [
    ("marlin", "ping_pong"),
    ("marlin", "advanced_ok"),
    ("marlin", "bytes"),
    ("grbl", "char_counting"),
]
FILES = {"segments": 20000, "long": 2000}
#: The worker's CPU per 1,000 lines at 250000 baud must stay at or under this (s):
#: what lets a Raspberry-Pi-class computer drive its printers (issue 11).
CPU_GOAL = 0.10
CPU_GOAL_BAUD = 250000
#: The CPU goal's cases run this many times each, in turns with the reference host,
#: and the run of least CPU is kept: on a shared machine a burst of someone else's
#: load only ever adds (one 20 s run here gave 0.200, three 10 s runs after it
#: 0.125 to 0.196), so it must not decide the verdict.
CPU_RUNS = 3


def cases(max_seconds: float) -> list[dict]:
    """The case matrix; long lines only without added latency, to keep the run short."""
    out = []
    for file, lines in FILES.items():
        for firmware, mode in MODES:
            for baud in (115200, 250000):
                latencies = (0, 4, 16) if file == "segments" else (0,)
                for latency in latencies:
                    out.append(
                        _case(file, lines, firmware, mode, baud, latency, max_seconds)
                    )
            out.append(_case(file, lines, firmware, mode, 0, 0, max_seconds))
    return out


def _case(file: str, lines: int, firmware: str, mode: str, baud: int, latency: int,
          max_seconds: float) -> dict:  # fmt: skip
    speed = f"{baud}" if baud else "unthrottled"
    return {
        "name": f"{file}/{firmware}-{mode}/{speed}/{latency}ms",
        "file": file, "lines": lines, "firmware": firmware, "mode": mode,
        "baud": baud, "latency_ms": latency, "max_seconds": max_seconds,
    }  # fmt: skip


def run(case: dict) -> dict:
    done = subprocess.run(
        [sys.executable, "-m", "bench.case", json.dumps(case)],
        cwd=ROOT, capture_output=True, text=True, check=False, timeout=900,
    )  # fmt: skip
    if done.returncode != 0:
        return {**case, "error": done.stderr.strip().splitlines()[-1:]}
    return json.loads(done.stdout.strip().splitlines()[-1])


def table(results: list[dict]) -> str:
    head = (
        f"{'case':52} {'lines':>6} {'s':>6} {'lines/s':>8} {'B/s':>6} {'rtt ms':>7} "
        f"{'use':>6} {'bound':>6} {'whole':>6} {'cpu/1k':>7}"
    )
    rows = [head, "-" * len(head)]
    for r in results:
        if "error" in r:
            rows.append(f"{r['name']:52} ERROR {r['error']}")
            continue
        cells = [_cell(r.get(k)) for k in ("link_use", "bound", "bound_whole_lines")]
        rows.append(
            f"{r['name']:52} {r['lines']:>6} {r['seconds']:>6.1f} {r['lines_per_s']:>8.1f} "
            f"{r['bytes_per_s']:>6.0f} {r.get('rtt_ms', 0):>7.2f} {cells[0]:>6} "
            f"{cells[1]:>6} {cells[2]:>6} {r['cpu_s_per_1k_lines']:>7.3f}"
        )
    return "\n".join(rows)


def _cell(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def whole_line_bound(r: dict) -> float | None:
    """The bound for a host that sends whole lines only (the safe kind; see README).

    The window is as many whole mean-sized lines as fit the 127-byte budget (and,
    with ADVANCED_OK, no more than BUFSIZE = 4 lines) instead of all 127 bytes.
    """
    if not r.get("baud") or r["mode"] == "ping_pong" or not r.get("mean_line_bytes"):
        return None
    size = r["mean_line_bytes"]
    lines = 127 // size
    if r["mode"] == "advanced_ok":
        lines = min(lines, 4)
    link = r["baud"] / 10
    return round(min(1.0, lines * size / (link * r["rtt_ms"] / 1000)), 3)


def checks(results: list[dict]) -> list[str]:
    """Windowed and GRBL cases: link use >= 0.9 (no latency) or >= 0.9 x bound.

    With latency the target is the whole-line bound: no host that writes whole lines
    can beat it (issue 2's decision). The 127-byte bound is printed beside it as
    `INFO`, never as a failure. Then the CPU goal (`cpu_checks`).
    """
    lines = []
    for r in results:
        if "error" in r:
            lines.append(f"FAIL {r['name']}: the case did not run: {r['error']}")
            continue
        if not r.get("baud") or r["mode"] == "ping_pong" or r.get("group"):
            continue
        if r["latency_ms"] == 0:
            targets = [("", 0.9)]
        else:
            targets = [("127-byte bound", 0.9 * r["bound"])]
            targets.append(("whole-line bound", 0.9 * r["bound_whole_lines"]))
        for label, target in targets:
            ok = r["link_use"] >= target
            verdict = "PASS" if ok else "FAIL"
            if label == "127-byte bound":
                verdict = "INFO " + ("above" if ok else "below")
            against = f" ({label})" if label else ""
            lines.append(
                f"{verdict} {r['name']}: link use {r['link_use']:.3f} "
                f">= {target:.3f}{against}"
            )
    return lines + cpu_checks(results)


def _has_reference(case: dict) -> bool:
    """The CPU goal's cases: 250000 baud, no added latency (both files)."""
    return case["baud"] == CPU_GOAL_BAUD and not case["latency_ms"]


def best_of(case: dict) -> tuple[dict, dict]:
    """*case* and its reference twin, CPU_RUNS times in turns: each side's run of
    least CPU (a run that failed is kept instead, so the failure shows)."""
    mine, theirs = [], []
    for _ in range(CPU_RUNS):
        mine.append(run(case))
        theirs.append(run(reference_twin(case)))
    return least_cpu(mine), least_cpu(theirs)


def least_cpu(runs: list[dict]) -> dict:
    """The run of least CPU per 1,000 lines, with every run's figure beside it."""
    failed = [r for r in runs if "error" in r or not r.get("cpu_s_per_1k_lines")]
    best = failed[0] if failed else min(runs, key=lambda r: r["cpu_s_per_1k_lines"])
    return {**best, "cpu_runs": [r.get("cpu_s_per_1k_lines") for r in runs]}


def reference_twin(case: dict) -> dict:
    """*case* run by bench/reference_host.py: the least any Python host does."""
    return {**case, "name": f"reference/{case['name']}", "host": "reference"}


def reference_lines(results: list[dict]) -> list[str]:
    """The worker's CPU per 1,000 lines beside the reference host's, case by case."""
    worker = {r["name"]: r for r in results if "error" not in r}
    lines = []
    for r in results:
        if r.get("group") != "reference" or "error" in r:
            continue
        mine = worker.get(r["name"].removeprefix("reference/"))
        if mine is None or not r["cpu_s_per_1k_lines"]:
            continue
        ratio = mine["cpu_s_per_1k_lines"] / r["cpu_s_per_1k_lines"]
        lines.append(
            f"INFO {mine['name']}: cpu/1k {mine['cpu_s_per_1k_lines']:.3f}, "
            f"{ratio:.1f} x the reference host's {r['cpu_s_per_1k_lines']:.3f} "
            f"(least of {_runs(mine)} against {_runs(r)}; wake-ups a line "
            f"{_wakes(mine)} against {_wakes(r)}; user space + kernel "
            f"{_split(mine)} against {_split(r)})"
        )
    return lines


def _split(result: dict) -> str:
    """The run's CPU a line split between the host's own code and its system calls."""
    user = result.get("cpu_user_per_1k_lines")
    system = result.get("cpu_system_per_1k_lines")
    if user is None or system is None:
        return "?"
    return f"{user:.3f} + {system:.3f}"


def _wakes(result: dict) -> str:
    """Turns of the host's loop a line: with long lines, two fit the firmware's
    127-byte buffer, so any host wakes once a line to keep the wire busy."""
    wakes = result.get("wakes_per_line")
    return f"{wakes:.2f}" if wakes is not None else "?"


def _runs(result: dict) -> str:
    return ", ".join(f"{cpu:.3f}" for cpu in result.get("cpu_runs") or [] if cpu)


def cpu_checks(results: list[dict]) -> list[str]:
    """Every case at 250000 baud without added latency, the 8 at once included:
    cpu/1k <= CPU_GOAL.

    Printed as `INFO`: the log and live-feed pairs (each switches one part of the
    worker off or on to show what it costs) and the cases with latency, where the
    window, not the worker, limits the lines a second, so the per-second costs
    (polls, log batches, progress) are shared by a fraction of the lines.
    """
    lines = []
    for r in results:
        if (
            "error" in r
            or r.get("baud") != CPU_GOAL_BAUD
            or r.get("group") == "reference"
        ):
            continue
        cpu = r.get("cpu_s_per_1k_lines")
        if cpu is None:
            continue
        verdict = "PASS" if cpu <= CPU_GOAL else "FAIL"
        if r.get("group") in ("log", "live") or r.get("latency_ms"):
            verdict = "INFO " + ("within" if cpu <= CPU_GOAL else "above")
        lines.append(f"{verdict} {r['name']}: cpu/1k {cpu:.3f} <= {CPU_GOAL:.3f}")
    return lines + reference_lines(results)


def finish(results: list[dict], out: Path) -> int:
    """Add the whole-line bound, print the table and the checks, write the JSON."""
    for r in results:
        if "error" not in r:
            r["bound_whole_lines"] = whole_line_bound(r)
    print("\n" + table(results))
    if summary := eight_summary(results):
        print("\n" + summary)
    verdicts = checks(results)
    print("\n" + "\n".join(verdicts))
    out.write_text(json.dumps(results, indent=1))
    return 1 if any(v.startswith("FAIL") for v in verdicts) else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max-seconds", type=float, default=20.0,
                        help="stop each case after this long (rates stay exact)")  # fmt: skip
    parser.add_argument("--only", default="", help="run cases whose name has this")
    parser.add_argument("--out", default=str(ROOT / "bench-results.json"))
    parser.add_argument("--from", dest="source", help="re-render a results file")
    parser.add_argument("--no-soak", dest="soak", action="store_false",
                        help="leave out the fault-injection soak (bench/soak.py)")  # fmt: skip
    options = parser.parse_args(argv)
    if options.source:
        return finish(json.loads(Path(options.source).read_text()), Path(options.out))
    results = []
    for case in cases(options.max_seconds):
        if options.only and options.only not in case["name"]:
            continue
        if _has_reference(case):
            result, reference = best_of(case)
            results += [result, {**reference, "group": "reference"}]
        else:
            result = run(case)
            results.append(result)
        print(f"{result['name']}: link use {result.get('link_use')}", flush=True)
    if options.only:
        return finish(results, Path(options.out))
    results += logging_cost(options.max_seconds)
    results += live_feed_cost(options.max_seconds)
    results += eight_at_once(options.max_seconds)
    failed = finish(results, Path(options.out))
    if options.soak:
        failed |= soak.main(
            ["--out", str(Path(options.out).with_name("bench-soak.json"))]
        )
    return failed


def on_off_pair(
    group: str,
    what: str,
    setting: str,
    values: tuple[object, object],
    max_seconds: float,
) -> list[dict]:
    """The same Marlin stream run twice, *setting* on then off; prints the ratio."""
    pair = []
    for value, label in zip(values, ("on", "off"), strict=True):
        case = _case("segments", 20000, "marlin", "advanced_ok", 250000, 0, max_seconds)
        case["name"] = f"{group}-{label}/marlin-advanced_ok/250000/0ms"
        case[setting] = value
        pair.append({**run(case), "group": group})
    on, off = pair
    if "error" not in on and "error" not in off:
        print(f"{what}: {on['lines_per_s']} lines/s with it, {off['lines_per_s']} "
              f"without (ratio {on['lines_per_s'] / off['lines_per_s']:.3f})")  # fmt: skip
    return pair


def logging_cost(max_seconds: float) -> list[dict]:
    """The response log on and off: logging must not slow the stream."""
    return on_off_pair("log", "logging cost", "log", (True, False), max_seconds)


def live_feed_cost(
    max_seconds: float, redis: str = "redis://127.0.0.1:6379/0"
) -> list[dict]:
    """The live feed published to Redis, and no Redis: publishing must not slow it."""
    try:
        import redis as redis_client

        redis_client.Redis.from_url(redis, socket_connect_timeout=2).ping()
    except Exception as error:
        print(f"live feed cost: skipped, no Redis at {redis} ({error})")
        return []
    return on_off_pair("live", "live feed cost", "redis", (redis, ""), max_seconds)


def eight_at_once(max_seconds: float) -> list[dict]:
    """8 Marlin printers (ADVANCED_OK) at 250000 streaming at the same time."""
    group = []
    for i in range(8):
        case = _case("segments", 20000, "marlin", "advanced_ok", 250000, 0, max_seconds)
        case["name"] = f"8-at-once/printer{i}/250000/0ms"
        group.append(case)
    with ThreadPoolExecutor(max_workers=8) as pool:
        results = list(pool.map(run, group))
    for r in results:
        r["group"] = "8-at-once"
    return results


def eight_summary(results: list[dict]) -> str:
    """One line for the 8-at-once section: link use and CPU per 1,000 lines."""
    ran = [r for r in results if r.get("group") == "8-at-once" and "error" not in r]
    if not ran:
        return ""
    uses = [r["link_use"] for r in ran]
    cpus = [r["cpu_s_per_1k_lines"] for r in ran]
    return (
        f"8 at once ({len(ran)} printers, 250000 baud): link use "
        f"{min(uses):.3f}-{max(uses):.3f} each, cpu/1k {min(cpus):.3f}-{max(cpus):.3f}"
    )


if __name__ == "__main__":
    sys.exit(main())
