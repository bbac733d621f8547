"""`make bench`, ETA section: the remaining time a print reports against the time
it really has left.

A real PrusaSlicer slice (tests/data) prints on the Marlin simulator with its motion
timed as a firmware times it (printers/simulator/_kinematics.py: trapezoids, classic
jerk, look-ahead over its 16 blocks, the file's M201/M203/M204/M205: a model
simpler than the analyser's), in real time: a quarter of an hour. (`--time-scale`
shortens it, but a scaled print runs at a pace the estimate only trusts after
five minutes of motion: at 0.4, 25 % reads 30 % high, 50 % and 75 % within 4 %.)
runhost's Celery worker analyses the file first; then the remaining time the job reports (`/printer/job`, as every client
reads it) is sampled, and at 25 %, 50 % and 75 % of the print it is held against
the time the job then really took to complete: within 5 % passes.

The heater waits are taken out of the file (M190/M109 become M140/M104): the
simulator's heaters are not the analyser's heater model, and heating is reported
apart from motion. This is a bench, not a test: it measures wall-clock time over
minutes, which a loaded machine skews.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import tempfile
import time
from pathlib import Path

import httpx

from tests.conftest import wait_for
from tests.hosts import Host
from tests.slices import PRUSA

ROOT = Path(__file__).resolve().parent.parent
CHECKS = (25.0, 50.0, 75.0)
#: Allowed error of the reported remaining time, as a share of the true one.
TOLERANCE = 0.05


def without_heater_waits(text: str) -> str:
    text = re.sub(r"^M190 ", "M140 ", text, flags=re.M)
    return re.sub(r"^M109 ", "M104 ", text, flags=re.M)


def print_and_sample(folder: Path, time_scale: float) -> tuple[list, float]:
    """Print the slice; the samples (seconds, time progress %, remaining s) and the
    second it completed, both on this process's monotonic clock."""
    host = Host(folder)
    host.migrate()
    host.add_simulated_printer("mk3", sim_args=f"--time-scale {time_scale}")
    key = host.add_user("op", role="operator")
    source = folder / "slice.gcode"
    source.write_text(without_heater_waits(PRUSA.read_text()))
    samples: list[tuple[float, float, float]] = []
    with host.running(celery=True):
        client = httpx.Client(base_url=host.url, headers={"X-Api-Key": key}, timeout=30)
        wait_for(
            lambda: host.query("SELECT state FROM printers_printer")[0][0] == "idle",
            60, "the printer to connect",
        )  # fmt: skip
        # Stored, analysed, then started: the print starts with its analysis ready.
        stored = client.post(
            "/printer/job/mk3",
            data={"a": "upload", "autostart": "0"},
            files={"filename": ("slice.gcode", source.read_bytes())},
        )
        stored.raise_for_status()
        job_id = stored.json()["data"]["id"]
        wait_for(
            lambda: host.query("SELECT state FROM jobs_fileanalysis") == [("done",)],
            120, "runhost's Celery worker to analyse the file",
        )  # fmt: skip
        client.post(
            "/printer/job/mk3", data={"a": "start", "id": job_id}
        ).raise_for_status()

        def sample() -> bool:
            jobs = client.get("/printer/job/mk3?a=list").json()["data"]
            job = next(j for j in jobs if j["id"] == job_id)
            if job["state"] != "printing":
                return job["state"] in ("completed", "failed", "aborted")
            if job.get("time_progress") is not None and job.get("eta") is not None:
                samples.append((time.monotonic(), job["time_progress"], job["eta"]))
            return False

        # Four samples a second (the pause paces the sampling).
        wait_for(sample, 3600, "the print to end", step=lambda: time.sleep(0.25))
        finished = time.monotonic()
        state = host.query("SELECT state FROM jobs_job")[0][0]
        if state != "completed":
            raise SystemExit(f"the print ended {state}: {host.log_tail()}")
    return samples, finished


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--time-scale", type=float, default=1.0,
        help="simulated motion time per real second (the pace correction takes "
        "0.33 to 3)",
    )  # fmt: skip
    parser.add_argument("--out", default=str(ROOT / "bench-eta.json"))
    options = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        samples, finished = print_and_sample(Path(folder), options.time_scale)
    if not samples:
        print("FAIL: no remaining time was reported while printing")
        return 1
    took = finished - samples[0][0]
    print(f"\nETA of {PRUSA.name} (heater waits out), time scale {options.time_scale}:")
    print("| progress (time) | remaining said | remaining really | error |")
    print("|---|---|---|---|")
    rows, ok = [], True
    for share in CHECKS:
        at, progress, said = next(s for s in samples if s[1] >= share)
        real = finished - at
        error = (said - real) / real
        ok &= abs(error) <= TOLERANCE
        rows.append({"progress": progress, "said": said, "real": real, "error": error})
        print(
            f"| {progress:.1f} % | {said:.1f} s | {real:.1f} s | {100 * error:+.1f} % |"
        )
    print(f"(printed for {took:.0f} s after the first sample)")
    verdict = "PASS" if ok else "FAIL"
    print(f"{verdict}: remaining time within {100 * TOLERANCE:.0f} % at 25/50/75 %")
    Path(options.out).write_text(json.dumps(rows, indent=1))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
