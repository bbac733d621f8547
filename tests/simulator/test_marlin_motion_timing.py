"""The simulated Marlin's move times: trapezoids, limits and classic jerk."""

from __future__ import annotations

import math

import pytest

from printers.simulator._kinematics import Kinematics, Limits, trapezoid
from printers.simulator._marlin_machine import MarlinMachine


def test_a_long_move_is_a_trapezoid() -> None:
    # 100 mm at 100 mm/s, 1000 mm/s², from and to the jerk speed of 10 mm/s.
    kinematics = Kinematics(Limits(travel_acceleration=1000.0))
    [seconds] = kinematics.plan((100.0, 0.0, 0.0, 0.0), 100.0)
    ramp = (100 - 10) / 1000  # each way
    ramp_length = (100**2 - 10**2) / 2000
    assert seconds == pytest.approx(2 * ramp + (100 - 2 * ramp_length) / 100)


def test_a_short_move_never_reaches_its_feedrate() -> None:
    seconds = trapezoid(1.0, 0.0, 200.0, 0.0, 1000.0)
    peak = math.sqrt(1000.0 * 1.0)  # half the length up, half down
    assert peak < 200
    assert seconds == pytest.approx(2 * peak / 1000)


def test_the_files_settings_change_the_time_as_the_firmware_would() -> None:
    def seconds_for(*settings: str) -> float:
        machine = MarlinMachine(lambda *a: None, planner=16, time_scale=1.0, now=0.0)
        handlers = machine.handlers()
        for line in settings:
            code, _, args = line.partition(" ")
            handlers[code](args, 0.0)
        return machine.kinematics.plan((200.0, 0.0, 0.0, 5.0), 200.0)[-1]

    plain = seconds_for()
    assert seconds_for("M204 P500") > plain  # slower acceleration
    assert seconds_for("M201 X200") > plain  # the X axis limits it
    assert seconds_for("M203 X50") == pytest.approx(200 / 50, rel=0.05)
    assert seconds_for("M220 S50") > 1.8 * plain
    assert seconds_for("M205 X30") < plain  # a faster start and stop
    assert seconds_for("M204 T100") == pytest.approx(plain)  # travel only


def test_a_straight_line_in_pieces_takes_about_as_long_as_one_move() -> None:
    whole = Kinematics().plan((100.0, 0.0, 0.0, 0.0), 100.0)[-1]
    pieces = Kinematics(lookahead=16)
    times: list[float] = []
    for _ in range(100):
        window = pieces.plan((1.0, 0.0, 0.0, 0.0), 100.0)
        # The moves still in the look-ahead are timed again; older ones stand.
        times[len(times) - len(window) + 1 :] = window
    assert len(times) == 100
    assert sum(times) == pytest.approx(whole, rel=0.03)
    # With one block of look-ahead, each piece must be able to stop: slower.
    short = Kinematics(lookahead=1)
    alone = sum(short.plan((1.0, 0.0, 0.0, 0.0), 100.0)[-1] for _ in range(100))
    assert alone > 1.1 * whole


def test_a_square_corner_slows_to_the_jerk_speed() -> None:
    kinematics = Kinematics(Limits(print_acceleration=1000.0))
    kinematics.plan((50.0, 0.0, 0.0, 1.0), 100.0)
    again, _ = kinematics.plan((0.0, 50.0, 0.0, 1.0), 100.0)
    # X stops and Y starts: each axis changes by the corner speed, at most 10 mm/s.
    corner = trapezoid(50.0, 10.0, 100.0, 10.0, 1000.0)
    assert again == pytest.approx(corner)
    straight = Kinematics(Limits(print_acceleration=1000.0))
    straight.plan((50.0, 0.0, 0.0, 1.0), 100.0)
    through, _ = straight.plan((50.0, 0.0, 0.0, 1.0), 100.0)
    assert through < again  # straight on keeps its speed


def test_the_simulated_printer_runs_moves_for_their_planned_time() -> None:
    machine = MarlinMachine(lambda *a: None, planner=16, time_scale=0.5, now=0.0)
    handlers = machine.handlers()
    handlers["G1"]("X100 F6000", 0.0)
    deadline = machine.planner.next_deadline()
    assert deadline == pytest.approx(
        0.5 * Kinematics().plan((100.0, 0, 0, 0), 100.0)[0]
    )
