"""`make bench`, the farm section: a full-size print farm on this machine.

PostgreSQL, Redis, one control plane and 3 worker hosts (each `runhost` in its own
process group and data directory) driving 32 simulated printers with motion timing
on (`--time-scale`, 0.25 by default: moves take a quarter of the firmware's time,
four times a real print's line rate, so a machine that keeps up here keeps up at
real speed; heat-ups and homing take no time, so the times compare streams, not
the firmware's waits), printing real slicer files (tests/farmrig). In one run, side by side:

1. Single-printer baseline: each file printed alone on one printer of the farm.
2. Capacity: one job per printer, all at once (a worker host's whole shelf
   printing): each job's time against the baseline's. This decides how many
   printers the machine drives with every job within 2 %.
3. The farm: 50 jobs with mixed requirements uploaded to the farm queue, while 100
   websocket clients follow the printers and an API load sends 50 GET requests a
   second; every job checked (once, on a matching printer, each simulator's record
   its jobs' files). Per job: its time against the baseline's (the slowdown) and
   how many printers were printing meanwhile; per printer: its worker's CPU
   (% of a core, from /proc/<pid>/stat) and CPU per 1,000 lines; the web's p95.
   The clients stand for browsers on other computers: they run in processes of
   their own (the watchers in two, the API load in one) at nice 10
   (tests/farmrig/crowd.py), as runhost runs daphne and Celery nicer than the
   printer workers (printers/supervisor.py); the rate the load really reached is
   reported beside the one asked for.
Both phases say where the CPU went (cores per kind of process).
4. The faults of tests/farmrun at full size (PostgreSQL away, Redis away, a
   worker host SIGKILLed), one fresh farm each; a dispatcher killed mid-claim is
   tests/farm/test_dispatcher_postgres.py.

Prints PASS/FAIL for each of issue 11's figures and writes bench-farm.json.

    python -m bench.farm [--printers 32] [--jobs 50] [--time-scale 0.25] [--no-faults]
"""

from __future__ import annotations

import argparse
import json
import secrets
import shutil
import signal
import statistics
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import TYPE_CHECKING, Any

import httpx

from bench.farm_figures import (
    CpuWatch,
    job_figures,
    load_latency,
    p95,
    rounded,
    run_checks,
)
from bench.farm_report import PRINTERS_GOAL, capacity_line, judge, summary
from tests.conftest import wait_for
from tests.farmrig.clients import ApiLoad, Watcher
from tests.farmrig.crowd import Crowd
from tests.farmrig.fleet import JobSpec, extent, meets
from tests.farmrig.processes import cpu_by_kind, shares
from tests.farmrig.rig import Farm, FarmConfig

if TYPE_CHECKING:
    from collections.abc import Callable

ROOT = Path(__file__).resolve().parent.parent
#: The farm's /metrics token: the server's own request latency comes from there.
METRICS_TOKEN = secrets.token_urlsafe(16)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hosts", type=int, default=3)
    parser.add_argument("--printers", type=int, default=PRINTERS_GOAL)
    parser.add_argument("--jobs", type=int, default=50)
    parser.add_argument("--time-scale", type=float, default=0.25)
    parser.add_argument("--clients", type=int, default=100)
    parser.add_argument("--rate", type=float, default=50.0, help="API requests/s")
    parser.add_argument("--long", action="store_true", help="add the long files")
    parser.add_argument("--no-faults", dest="faults", action="store_false")
    parser.add_argument("--out", default=str(ROOT / "bench-farm.json"))
    options = parser.parse_args(argv)
    # A SIGTERM unwinds (every runhost and simulator of the farm is stopped).
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    config = FarmConfig(
        hosts=options.hosts, printers=options.printers, jobs=options.jobs,
        time_scale=options.time_scale, instant_waits=True, lease_seconds=10.0,
        long_files=options.long, patience=8.0,
        env={"PRINTHOST_METRICS_TOKEN": METRICS_TOKEN},
    )  # fmt: skip
    root = Path(tempfile.mkdtemp(prefix="printhost-bench-farm-"))
    out = Path(options.out)
    try:
        report = run_farm(root / "farm", config, options)
        verdicts = _write(report, out)
        print("\n" + summary(report) + "\n\n" + "\n".join(verdicts), flush=True)
        if options.faults:
            report["faults"] = run_faults(root, config)
            verdicts = _write(report, out)
            print("\n" + "\n".join(v for v in verdicts if "fault:" in v))
    finally:
        shutil.rmtree(root, ignore_errors=True)
    return 1 if any(v.startswith("FAIL") for v in verdicts) else 0


def _write(report: dict, out: Path) -> list[str]:
    """The verdicts so far, written with the figures (a long run keeps what it has)."""
    verdicts = judge(report)
    report["verdicts"] = verdicts
    out.write_text(json.dumps(report, indent=1, default=str))
    return verdicts


# -- the farm -------------------------------------------------------------------------


def run_farm(folder: Path, config: FarmConfig, options: argparse.Namespace) -> dict:
    farm = Farm(folder, config)
    report: dict[str, Any] = {"config": {**config.__dict__, "env": None}}
    started = time.monotonic()
    try:
        farm.setup()
        farm.start()
        report["start_seconds"] = round(time.monotonic() - started, 1)
        print(f"farm: {config.printers} printers on {config.hosts} hosts up in "
              f"{report['start_seconds']} s", flush=True)  # fmt: skip
        report["baseline"] = baseline(farm)
        print(f"baseline: {report['baseline']}", flush=True)
        report["capacity"] = capacity_phase(farm, report["baseline"])
        print(f"capacity: {capacity_line(report['capacity'])}", flush=True)
        report.update(farm_phase(farm, report["baseline"], options))
    except Exception:
        report["error"] = traceback.format_exc()
        print(report["error"], flush=True)
    finally:
        farm.close()
    return report


def baseline(farm: Farm) -> dict[str, float]:
    """Seconds each file of the mix takes printed alone (one printer, the farm idle).

    Each file on a printer that has not printed yet. The simulators' heat-ups and
    homing take no time (`--instant-waits`): they are the firmware's time, not the
    host's, and their length depends on where the last job left the printer. With
    them, a job on a printer still warm from its last one ran up to 10 % faster
    than its cold baseline, and one whose last job left the head high homed about
    1.8 s longer (the simulator homes Z at 4 mm/s): both hid what the stream did.
    """
    times = {}
    used: set[str] = set()
    for job in {j.file: j for j in farm.jobs}.values():
        slug = next(
            p.slug
            for p in farm.printers
            if p.slug not in used and meets({}, p, extent(job.file))
        )
        used.add(slug)
        job_id = farm.upload_to(slug, job)
        farm.tend(lambda j=job_id: _state(farm, j) in ("completed", "failed"), 600,
                  f"the baseline of {job.file}")  # fmt: skip
        assert _state(farm, job_id) == "completed"
        times[job.file] = _duration(farm, job_id)
        farm.other_jobs.add(job_id)
        farm.tend(lambda s=slug: _printer_state(farm, s) == "idle", 60, "a clear bed")
    farm.record_offsets = {slug: len(sim.executed()) for slug, sim in farm.sims.items()}
    return times


CAPACITY_FILE = "prusaslicer-2.5_flat-box.gcode"


def capacity_phase(farm: Farm, base: dict[str, float]) -> dict:
    """One job per printer, no requirements, uploaded at once; no web load."""
    jobs = [
        JobSpec(f"shelf{n + 1:02d}-flat-box.gcode", CAPACITY_FILE)
        for n in range(len(farm.printers))
    ]
    before = set(farm.uploaded)
    cpu, began = cpu_by_kind(), time.monotonic()
    farm.upload(jobs)
    farm.tend(farm.all_done, 1800, "every capacity job to run")
    seconds = time.monotonic() - began
    mine = set(farm.uploaded) - before
    figures = [j for j in job_figures(farm, base) if j["farm_job"] in mine]
    return {
        "seconds": round(seconds, 1),
        "jobs": figures,
        "cpu_cores": shares(cpu, cpu_by_kind(), seconds),
    }


def farm_phase(farm: Farm, base: dict[str, float], options: argparse.Namespace) -> dict:
    """The 50 jobs under web load; the figures and the checks."""
    url = f"ws://127.0.0.1:{farm.control.port}/ws/printers"
    slugs = [p.slug for p in farm.printers]
    watchers = [
        Watcher(f"{url}/{slugs[i % len(slugs)]}/", slugs[i % len(slugs)])
        for i in range(options.clients)
    ]
    paths = [f"/printer/state/{s}" for s in slugs] + ["/printer/list", "/printer/farm"]
    load = ApiLoad(farm.control.url, farm.operator, paths, options.rate)
    crowd = Crowd(watchers, farm.operator, load)
    crowd.start()
    try:
        wait_for(crowd.connected, 60, "the websocket clients to connect")
        cpu = CpuWatch(farm)
        kinds, began = cpu_by_kind(), time.monotonic()
        before = set(farm.uploaded)
        farm.upload()
        farm.tend(
            lambda: cpu.sample() or farm.all_done(), 3600, "every farm job to run"
        )
        seconds = time.monotonic() - began
        out: dict[str, Any] = {"farm_seconds": round(seconds, 1)}
        out["cpu_cores"] = shares(kinds, cpu_by_kind(), seconds)
    finally:
        crowd.stop()
    out["checks"] = run_checks(farm)
    mine = set(farm.uploaded) - before
    out["jobs"] = [j for j in job_figures(farm, base) if j["farm_job"] in mine]
    out["workers"] = cpu.figures()
    received = sum(len(w.lines) for w in watchers)
    out["web"] = {
        "clients": len(watchers),
        "client_reconnects": sum(w.reconnects for w in watchers),
        "lines_received": received,
        "api_rate": options.rate,
        "api_rate_achieved": rounded(load.achieved_rate(), 2),
        "api_issued": load.issued,
        "api_sent": load.sent,
        "api_requests": len(load.latencies) + load.errors,
        "api_errors": load.errors,
        "api_p95_ms": None if load.p95() is None else round(load.p95() * 1000, 1),
        "api_median_ms": round(statistics.median(load.latencies) * 1000, 1)
        if load.latencies
        else None,
        "client_lag_p95_ms": round(p95(load.lags) * 1000, 1) if load.lags else None,
        "server": server_latency(farm),
    }
    return out


def server_latency(farm: Farm) -> dict[str, Any]:
    """The control plane's own time for the load's GETs, from its /metrics histogram
    (reaching Django to the response; bucket bounds, so "at most"): what the
    client's latency adds is the requests' wait for a connection and for daphne."""
    headers = {"Authorization": f"Bearer {METRICS_TOKEN}"}
    try:
        with httpx.Client(base_url=farm.control.url, timeout=30) as client:
            text = client.get("/metrics", headers=headers).text
    except httpx.HTTPError as error:
        return {"error": repr(error)}
    return load_latency(text)


def _state(farm: Farm, job_id: int) -> str:
    return farm.query("SELECT state FROM jobs_job WHERE id = %s", job_id)[0][0]


def _printer_state(farm: Farm, slug: str) -> str:
    return farm.query("SELECT state FROM printers_printer WHERE slug = %s", slug)[0][0]


def _duration(farm: Farm, job_id: int) -> float:
    start, end = farm.query(
        "SELECT started_at, finished_at FROM jobs_job WHERE id = %s", job_id
    )[0]
    return (end - start).total_seconds()


# -- the faults at full size ---------------------------------------------------------


def run_faults(root: Path, config: FarmConfig) -> dict[str, str]:
    """Each fault test of tests/farmrun against a fresh full-size farm (one round of
    jobs: one per printer)."""
    from tests.farmrun import (
        test_farm_database_away,
        test_farm_host_killed,
        test_farm_redis_away,
    )

    tests: dict[str, Callable[..., None]] = {
        "postgresql away": test_farm_database_away.test_every_print_completes_with_the_database_away_for_longer_than_the_lease,
        "redis away": test_farm_redis_away.test_prints_go_on_and_clients_catch_up_with_redis_away,
        "worker host killed": test_farm_host_killed.test_a_killed_worker_host_leaves_its_runs_interrupted_and_resumable,
    }
    results = {}
    for index, (name, test) in enumerate(tests.items()):
        farms: list[Farm] = []
        make = _factory(root / f"fault{index}", config, farms)
        began = time.monotonic()
        try:
            test(make)
            results[name] = f"ok ({time.monotonic() - began:.0f} s)"
        except Exception as error:
            results[name] = f"failed: {type(error).__name__}: {error}"[:2000]
        finally:
            for farm in farms:
                farm.close()
        print(f"fault {name}: {results[name][:300]}", flush=True)
    return results


def _factory(folder: Path, config: FarmConfig, farms: list[Farm]) -> Callable:
    """What a fault test asks for (`make_farm`): a full-size farm, set up."""

    def make(**changes: object) -> Farm:
        # One job a printer, all printing at once: the tests cut every print.
        values = {
            **config.__dict__, "jobs": config.printers, "mixed": False,
            "lease_seconds": 3.0,
        }  # fmt: skip
        farm = Farm(folder, FarmConfig(**{**values, **changes}))
        farms.append(farm)
        farm.setup()
        return farm

    return make


if __name__ == "__main__":
    sys.exit(main())
