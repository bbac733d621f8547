"""`make bench`, ETA section: the remaining time a print reports against the time
it really has left.

A real PrusaSlicer slice (tests/data) prints on the Marlin simulator with its motion
timed as a firmware times it (printers/simulator/_kinematics.py: trapezoids, classic
jerk, look-ahead over its 16 blocks, the file's M201/M203/M204/M205: a model
simpler than the analyser's), in real time: a quarter of an hour. runhost's Celery
worker analyses the file first; then the remaining time the job reports
(`/printer/job`, as every client reads it) is sampled, and at 25 %, 50 % and 75 % of
the print it is held against the time the job then really took to complete: within
5 % passes. The printing and sampling are tests/eta_run.py's, which the ETA
end-to-end test (tests/analysis/test_eta_end_to_end.py) runs on a five-minute slice
at a time scale of 0.4.

`--time-scale` shortens the run (0.4: six minutes): the machine then runs steadily
at 0.4 of the analysed pace, which a print's estimate trusts fully once a fifth of
its motion has run (jobs/eta.py), so the scaled run is held to the same 5 %.

The heater waits are taken out of the file (M190/M109 become M140/M104): the
simulator's heaters are not the analyser's heater model, and heating is reported
apart from motion. This is a bench, not a test: it measures wall-clock time over
minutes, which a loaded machine skews.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from tests.eta_run import CHECKS, TOLERANCE, print_and_sample
from tests.slices import PRUSA

ROOT = Path(__file__).resolve().parent.parent


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--time-scale", type=float, default=1.0,
        help="real seconds per firmware second of motion (the pace correction "
        "takes 0.33 to 3)",
    )  # fmt: skip
    parser.add_argument("--out", default=str(ROOT / "bench-eta.json"))
    options = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        run = print_and_sample(Path(folder), PRUSA, options.time_scale)
    took = run.took - run.samples[0].elapsed
    print(f"\nETA of {PRUSA.name} (heater waits out), time scale {options.time_scale}:")
    print(run.table())
    checks = run.checks()
    ok = all(abs(check.error) <= TOLERANCE for check in checks)
    rows = [
        {"progress": c.progress, "said": c.said, "real": c.real, "error": c.error}
        for c in checks
    ]
    print(f"(printed for {took:.0f} s after the first sample)")
    verdict = "PASS" if ok else "FAIL"
    shares = "/".join(f"{share:.0f}" for share in CHECKS)
    print(f"{verdict}: remaining time within {100 * TOLERANCE:.0f} % at {shares} %")
    Path(options.out).write_text(json.dumps(rows, indent=1))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
