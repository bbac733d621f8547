"""ETA end to end: a real slice printed on the simulator reports the time it has left.

A flat PrusaSlicer slice (tests/data/prusaslicer-2.5_flat-box.gcode: a 20 x 20 x
2 mm box, five minutes of motion by its analysis) prints on the Marlin simulator
under runhost, its moves timed as a firmware times them (acceleration, classic
jerk, look-ahead over 16 planner blocks: printers/simulator/_kinematics.py) at 0.4
of their firmware time: the print takes two minutes, and the machine runs steadily
at 0.4 of the analysed pace, as a printer with an inexact motion profile runs at
its own. runhost's Celery worker analyses the file first. The remaining time the
job reports (`/printer/job?a=list`) at 25, 50 and 75 % of its time progress is
held against the time the print then really took.

The print is as short as the check allows: 5 % at 75 % leaves a second and a half
of the half minute left there. The job's progress is saved about once a second;
the remaining time is reckoned for the moment of that save and brought to now
(`Job.progress_at`), so the save's age is not an error. The analysis does not time
the start's homing, which is.

(`make bench`'s ETA section prints the quarter-hour slice the same way in real time:
bench/eta.py.)
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.eta_run import TOLERANCE, print_and_sample

pytestmark = pytest.mark.slow

FLAT = (
    Path(__file__).resolve().parent.parent / "data" / "prusaslicer-2.5_flat-box.gcode"
)
#: Real seconds per firmware second of motion (the pace correction takes 0.33 to 3).
TIME_SCALE = 0.4


@pytest.mark.timeout(480)
def test_a_real_slice_on_a_time_scaled_simulator_reports_its_remaining_time_within_5_percent(
    tmp_path: Path,
) -> None:
    run = print_and_sample(tmp_path, FLAT, TIME_SCALE, timeout=300)
    table = run.table()
    print(f"\nETA of {FLAT.name}, time scale {TIME_SCALE}:\n{table}")
    # The machine really ran at its own pace, not the model's: what is checked
    # below is the pace correction, not a print that happened to run as analysed.
    assert run.took == pytest.approx(TIME_SCALE * run.motion_seconds, rel=0.1), table
    for check in run.checks():
        assert abs(check.error) <= TOLERANCE, table
