"""The height a resume takes the nozzle to be at after a stop (`stop_z`): the lowest
it may be, counting the moves the firmware's planner may still hold."""

from __future__ import annotations

import pytest

from jobs.models import Job
from jobs.resume.planning import read_point
from printers.models import Printer

pytestmark = pytest.mark.django_db

#: Heat, home, the first layer at Z 0.2 (30 extruding moves).
HEAD = [
    "M140 S60", "M104 S210", "G28", "G90", "M82", "G92 E0", "G1 Z0.2 F600",
    *(f"G1 X{10 + i} Y10 E{0.1 * (i + 1):.2f} F1200" for i in range(30)),
]  # fmt: skip
LAYER_TWO = "G1 Z0.4 F600"
MOVES = [f"G1 X{40 - i} Y12 E{3.1 + 0.1 * i:.2f} F1200" for i in range(15)]
UNSENT = ["G1 X0 Y0"] * 5


@pytest.mark.parametrize(
    "tail",
    [
        # The layer change is the oldest of the 16 moves in the planner: it may not
        # have run, so the nozzle may still be at 0.2.
        [LAYER_TWO, *MOVES, *UNSENT],
        # Commands that are not moves between them: the planner holds 16 moves, so
        # the layer change is among them all the same.
        [LAYER_TWO, *MOVES[:14], "M106 S200", "M204 S800", "M73 P50", *UNSENT],
    ],
)
def test_the_stop_height_is_the_lowest_the_planners_moves_allow(
    make_printer, make_job, tail
):
    job = make_job(make_printer(state=Printer.State.IDLE), "\n".join(HEAD + tail))
    stop = len(HEAD) + len(tail) - len(UNSENT)  # acknowledged up to the unsent moves
    Job.objects.filter(pk=job.pk).update(state=Job.State.INTERRUPTED, lines_acked=stop)
    job.refresh_from_db()
    point, _ = read_point(job, stop)
    assert point.stop_z == pytest.approx(0.2)
    assert point.state.position[2] == pytest.approx(0.4)
