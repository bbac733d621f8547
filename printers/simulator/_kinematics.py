"""How long the simulated Marlin takes for a move: acceleration, jerk, limits.

Sans-IO: `Kinematics.plan(delta, feedrate)` gives the move's seconds, and the new
seconds of the move before it (its exit speed is only known once this one comes).

The model is a firmware's in outline, and deliberately simpler than the host's
analyser (jobs/analysis/planner.py: junction deviation, look-ahead over the whole
file), so the two can be held against each other:

- each move is a trapezoid: it accelerates from its entry speed to its nominal
  speed and brakes to its exit speed, with the acceleration of M204 (P for moves
  that extrude, R for retracts, T for travel), lowered so no axis passes its M201;
- the nominal speed is F (scaled by M220) lowered so no axis passes its M203;
- the speed through a corner is classic jerk (M205 X Y Z E): the fastest speed at
  which no axis's velocity changes by more than its jerk; from a standstill a move
  starts at its jerk speed;
- look-ahead over the planner's blocks (16, as Marlin's BLOCK_BUFFER_SIZE): the
  last move queued brakes to its jerk speed, and every move still waiting is timed
  again when a new one arrives (two passes, backwards then forwards, as Marlin's
  planner does), so a line cut in pieces keeps its speed. Unlike the analyser, the
  look-ahead stops at the blocks queued, as a firmware's does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = ["Kinematics", "Limits", "trapezoid"]


@dataclass(slots=True)
class Limits:
    """Marlin 2.1's Configuration.h defaults (mm, mm/s, mm/s²), X Y Z E."""

    max_feedrate: list[float] = field(default_factory=lambda: [300.0, 300.0, 5.0, 25.0])
    max_acceleration: list[float] = field(
        default_factory=lambda: [3000.0, 3000.0, 100.0, 10000.0]
    )
    print_acceleration: float = 3000.0
    retract_acceleration: float = 3000.0
    travel_acceleration: float = 3000.0
    jerk: list[float] = field(default_factory=lambda: [10.0, 10.0, 0.3, 5.0])
    #: M220 S (1.0 = 100 %).
    speed_factor: float = 1.0


def trapezoid(
    length: float, entry: float, cruise: float, exit: float, accel: float
) -> float:
    """Seconds to cover *length* from *entry* to *exit* speed, at most *cruise*."""
    if length <= 0.0:
        return 0.0
    if accel <= 0.0:
        return length / max(cruise, 1e-9)
    peak = math.sqrt(max(0.0, (2 * accel * length + entry**2 + exit**2) / 2))
    top = min(cruise, peak)
    up = max(0.0, top - entry) / accel
    down = max(0.0, top - exit) / accel
    ramps = (top**2 - entry**2) / (2 * accel) + (top**2 - exit**2) / (2 * accel)
    return up + down + max(0.0, length - ramps) / max(top, 1e-9)


@dataclass(slots=True)
class _Move:
    length: float
    unit: tuple[float, float, float, float]
    cruise: float
    accel: float
    #: The fastest it may enter: the corner with the move before, or its jerk
    #: speed from a standstill.
    corner: float
    #: Its speed from and to a standstill.
    stop: float
    entry: float = 0.0
    exit: float = 0.0

    def seconds(self) -> float:
        return trapezoid(self.length, self.entry, self.cruise, self.exit, self.accel)


class Kinematics:
    """The planner's arithmetic over a window of the last moves; `limits` change as
    G-code sets them."""

    def __init__(self, limits: Limits | None = None, lookahead: int = 16) -> None:
        self.limits = limits or Limits()
        self.lookahead = max(1, lookahead)
        self._window: list[_Move] = []

    def stop(self) -> None:
        """The machine stood still (a wait, a quickstop): the next move starts anew."""
        self._window = []

    def plan(
        self,
        delta: tuple[float, float, float, float],
        feedrate: float,
        length: float | None = None,
    ) -> list[float]:
        """Add a move by *delta* (X Y Z E, mm) at *feedrate* (mm/s); *length* is an
        arc's, when it is not the chord's. Returns the seconds of the moves in the
        look-ahead window, oldest first, this one last (an empty list for a move
        of no length)."""
        limits = self.limits
        xyz = math.sqrt(delta[0] ** 2 + delta[1] ** 2 + delta[2] ** 2)
        chord = xyz or abs(delta[3])
        length = length or chord
        if length <= 0.0:
            return []
        scale = 1.0 / chord if chord > 0.0 else 0.0  # a full circle has no chord
        unit = (delta[0] * scale, delta[1] * scale, delta[2] * scale, delta[3] * scale)
        cruise = max(feedrate, 0.01) * limits.speed_factor
        if xyz > 0.0:
            accel = (
                limits.print_acceleration
                if delta[3] > 0.0
                else limits.travel_acceleration
            )
        else:
            accel = limits.retract_acceleration
        for axis in range(4):
            share = abs(unit[axis])
            if share > 0.0:
                cruise = min(cruise, limits.max_feedrate[axis] / share)
                accel = min(accel, limits.max_acceleration[axis] / share)
        stop = self._jerk_speed(unit, cruise)
        window = self._window
        corner = self._corner(window[-1], unit, cruise) if window else stop
        move = _Move(length, unit, cruise, accel, corner, stop)
        if not window:
            move.entry = stop
        window.append(move)
        if len(window) > self.lookahead:
            del window[0]
        self._replan()
        return [item.seconds() for item in window]

    def _replan(self) -> None:
        """Marlin's two passes: backwards, the fastest each move may enter and still
        slow down in time (the last one down to its stop speed); forwards, the
        fastest it can reach from the one before. The oldest keeps its entry (it may
        be running)."""
        window = self._window
        last = window[-1]
        last.exit = last.stop
        for index in range(len(window) - 1, 0, -1):
            move = window[index]
            move.entry = min(
                move.corner, math.sqrt(move.exit**2 + 2 * move.accel * move.length)
            )
            window[index - 1].exit = move.entry
        for index, move in enumerate(window):
            if index:
                move.entry = window[index - 1].exit
            move.exit = min(
                move.exit, math.sqrt(move.entry**2 + 2 * move.accel * move.length)
            )

    def _jerk_speed(self, unit: tuple[float, ...], cruise: float) -> float:
        """Speed a move may start at from (or stop to) a standstill."""
        speed = cruise
        for axis in range(4):
            share = abs(unit[axis])
            if share > 0.0:
                speed = min(speed, self.limits.jerk[axis] / share)
        return speed

    def _corner(self, before: _Move, unit: tuple[float, ...], cruise: float) -> float:
        """Classic jerk: the fastest common speed whose per-axis change fits."""
        speed = min(before.cruise, cruise)
        for axis in range(4):
            change = abs(before.unit[axis] - unit[axis]) * speed
            if change > self.limits.jerk[axis]:
                speed *= self.limits.jerk[axis] / change
        return speed
