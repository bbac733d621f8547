"""The printer behind Marlin's command queue: motion, heaters and what each G/M code does.

A handler takes (arguments, now) and either finishes at once (returns None) or
is a generator that yields what it waits for: a time (float) or a condition
(callable -> bool). The firmware's executor resumes it with the current time.
"""

from __future__ import annotations

import math
import re
from typing import TYPE_CHECKING

from printers.simulator import _marlin_text as text
from printers.simulator._heaters import Heater
from printers.simulator._kinematics import Kinematics
from printers.simulator._motion import Planner, distance

if TYPE_CHECKING:
    from collections.abc import Callable, Generator

    Wait = float | Callable[[], bool]
    Job = Generator[Wait, float, None]
    Handler = Callable[[str, float], Job | None]

__all__ = ["MarlinMachine", "words"]

#: Initial feedrate (mm/min) before any F word.
DEFAULT_FEEDRATE = 1500.0
STEPS_PER_MM = (80.0, 80.0, 400.0)
_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))?")


def words(args: str) -> dict[str, float]:
    """`X10 Y-2.5 F3000` -> {"X": 10.0, ...}; a letter without a number counts as 0."""
    try:  # the common, spaced form, without a regex
        return {t[0].upper(): float(t[1:]) if len(t) > 1 else 0.0 for t in args.split()}
    except ValueError:  # `X10Y5`, `X 10`, stray characters
        return {m[0].upper(): float(m[1]) if m[1] else 0.0 for m in _WORD.findall(args)}


class MarlinMachine:
    """Planner, position and heaters of a one-extruder printer with a heated bed."""

    def __init__(
        self,
        output: Callable[..., None],
        *,
        planner: int,
        time_scale: float,
        now: float,
        instant_waits: bool = False,
    ) -> None:
        self._print = output
        self.time_scale = time_scale
        self.planner = Planner(planner, (0.0, 0.0, 0.0, 0.0))
        self.kinematics = Kinematics(lookahead=planner)
        self.position = [0.0, 0.0, 0.0, 0.0]
        self.relative = False
        self.relative_e = False
        self.feedrate = DEFAULT_FEEDRATE
        #: Heat-ups and homing take no time (moves and dwells keep theirs).
        self.instant_waits = instant_waits
        # 0: heaters jump to target (no motion timing, or the waits left out)
        rate = 1.0 / time_scale if time_scale and not instant_waits else 0.0
        self.hotend = Heater(4.0 * rate, 2.0 * rate, now)
        self.bed = Heater(1.0 * rate, 0.5 * rate, now)
        #: A reply that replaces the plain ok (M105's `ok T:...`).
        self.custom_ok: str | None = None
        #: Set by M108: the running heat-up wait gives up.
        self.cancel_wait = False
        self._stops = 0

    def quickstop(self, now: float) -> None:
        """M410: drop every planned move; the machine stays where it stopped."""
        self.position = list(self.planner.clear(now))
        self.kinematics.stop()
        self._stops += 1

    def switch_off(self, now: float) -> None:
        """kill(): heaters off, motion gone."""
        self.planner.clear(now)
        self.hotend.set_target(0, now)
        self.bed.set_target(0, now)

    def temperatures(self, now: float) -> str:
        """print_heater_states(): `T:21.00 /0.00 B:21.00 /0.00 T0:... @:0 B@:0`."""
        hot, bed = self.hotend, self.bed
        hot.update(now)
        bed.update(now)
        t = f"{hot.temp:.2f} /{hot.target:.2f}"
        b = f"{bed.temp:.2f} /{bed.target:.2f}"
        return f"T:{t} B:{b} T0:{t} @:{hot.power} B@:{bed.power}"

    def handlers(self) -> dict[str, Handler]:
        table: dict[str, Handler] = {
            "G0": self._move,
            "G1": self._move,
            "G2": lambda a, n: self._move(a, n, arc=-1),
            "G3": lambda a, n: self._move(a, n, arc=1),
            "G4": self._g4,
            "G28": self._g28,
            "G90": lambda a, n: self._set_relative(xyz=False, e=False),
            "G91": lambda a, n: self._set_relative(xyz=True, e=True),
            "G92": self._g92,
            "M82": lambda a, n: self._set_relative(xyz=self.relative, e=False),
            "M83": lambda a, n: self._set_relative(xyz=self.relative, e=True),
            "M104": lambda a, n: self._set_temp(self.hotend, a, n, wait=False),
            "M105": self._m105,
            "M109": lambda a, n: self._set_temp(self.hotend, a, n, wait=True),
            "M114": self._m114,
            "M118": self._m118,
            "M140": lambda a, n: self._set_temp(self.bed, a, n, wait=False),
            "M190": lambda a, n: self._set_temp(self.bed, a, n, wait=True),
            "M400": self._m400,
            "T0": lambda a, n: None,
        }
        for code in text.SILENT:
            table[code] = lambda a, n: None
        # Motion settings (answered with a plain ok, as Marlin does).
        table.update(
            M201=lambda a, n: self._limits(a, "max_acceleration"),
            M203=lambda a, n: self._limits(a, "max_feedrate"),
            M204=lambda a, n: self._accelerations(a),
            M205=lambda a, n: self._limits(a, "jerk"),
            M220=lambda a, n: self._speed_factor(a),
        )
        for code, lines in text.FIXED_REPLIES.items():
            table[code] = lambda a, n, lines=lines: self._print(*lines)
        return table

    # -- motion ----------------------------------------------------------------------

    def _move(self, args: str, now: float, arc: int = 0) -> Job | None:
        """G0/G1 (arc 0), G2 (arc -1, clockwise), G3 (arc 1)."""
        given = words(args)
        if given.get("F", 0.0) > 0:
            self.feedrate = given["F"]
        start = self.position
        target = list(start)
        for axis, letter in enumerate("XYZE"):
            if letter in given:
                relative = self.relative_e if letter == "E" else self.relative
                target[axis] = (
                    start[axis] + given[letter] if relative else given[letter]
                )
        length = distance(tuple(start[:3]), tuple(target[:3]))
        if arc:
            length = _arc_length(start, target, given, arc)
        self.position = target
        self.planner.advance(now)
        if self.planner.idle():
            self.kinematics.stop()  # the head stands still: this move starts anew
        delta = (
            target[0] - start[0],
            target[1] - start[1],
            target[2] - start[2],
            target[3] - start[3],
        )
        times = self.kinematics.plan(
            delta, self.feedrate / 60.0, length if arc else None
        )
        if not times:
            times = [0.0]
        self.planner.retime([t * self.time_scale for t in times[:-1]])
        seconds = times[-1] * self.time_scale
        if self.planner.has_room():
            self.planner.add(seconds, tuple(target), now, rapid=False)
            return None
        return self._wait_for_room(seconds, tuple(target))

    def _wait_for_room(self, seconds: float, target: tuple[float, ...]) -> Job:
        """The ok of a move waits until the move is in the planner."""
        stops = self._stops
        now = yield self.planner.has_room
        while not self.planner.has_room() and stops == self._stops:
            now = yield self.planner.has_room
        if stops == self._stops:  # a quickstop refuses the move that was waiting
            self.planner.add(seconds, target, now, rapid=False)

    def _sync(self, now: float) -> Generator[Wait, float, float]:
        """planner.synchronize(): wait until every queued move has run."""
        while not self.planner.idle():
            now = yield self.planner.idle
        self.kinematics.stop()
        return now

    def _limits(self, args: str, name: str) -> None:
        """M201 (max acceleration), M203 (max feedrate), M205 (jerk): X Y Z E."""
        given = words(args)
        values = getattr(self.kinematics.limits, name)
        for axis, letter in enumerate("XYZE"):
            if given.get(letter, 0.0) > 0.0:
                values[axis] = given[letter]

    def _accelerations(self, args: str) -> None:
        """M204: S (print and travel, older firmware), P print, R retract, T travel."""
        given, limits = words(args), self.kinematics.limits
        if given.get("S", 0.0) > 0.0:
            limits.print_acceleration = limits.travel_acceleration = given["S"]
        for letter, name in (
            ("P", "print_acceleration"),
            ("R", "retract_acceleration"),
            ("T", "travel_acceleration"),
        ):
            if given.get(letter, 0.0) > 0.0:
                setattr(limits, name, given[letter])

    def _speed_factor(self, args: str) -> None:
        """M220 S<percent>."""
        given = words(args)
        if given.get("S", 0.0) > 0.0:
            self.kinematics.limits.speed_factor = given["S"] / 100.0

    def _sleep(self, seconds: float, now: float) -> Generator[Wait, float, float]:
        until = now + seconds * self.time_scale
        while now < until:
            now = yield until
        return now

    def _set_relative(self, *, xyz: bool, e: bool) -> None:
        self.relative = xyz
        self.relative_e = e

    def _m400(self, args: str, now: float) -> Job:
        yield from self._sync(now)

    def _g4(self, args: str, now: float) -> Job:
        given = words(args)
        seconds = given["P"] / 1000.0 if "P" in given else given.get("S", 0.0)
        now = yield from self._sync(now)
        yield from self._sleep(seconds, now)

    def _g28(self, args: str, now: float) -> Job:
        now = yield from self._sync(now)
        given = words(args)
        axes = [i for i, letter in enumerate("XYZ") if letter in given] or [0, 1, 2]
        x, y, z, _ = self.position
        seconds = 1.0 + max(abs(x), abs(y)) / 50.0 + abs(z) / 4.0
        if self.instant_waits:
            seconds = 0.0
        now = yield from self._sleep(seconds, now)
        for axis in axes:  # `G28 X Y` homes X and Y only
            self.position[axis] = 0.0
        self.planner.set_origin(tuple(self.position))
        self._m114("", now)

    def _g92(self, args: str, now: float) -> None:
        given = words(args)
        for axis, letter in enumerate("XYZE"):
            if letter in given:
                self.position[axis] = given[letter]
        if not given:
            self.position = [0.0, 0.0, 0.0, 0.0]
        self.planner.set_origin(tuple(self.position))

    def _m114(self, args: str, now: float) -> None:
        x, y, z, e = self.position
        actual = self.planner.position(now)
        counts = " ".join(
            f"{axis}:{round(actual[i] * STEPS_PER_MM[i])}"
            for i, axis in enumerate("XYZ")
        )
        self._print(f"X:{x:.2f} Y:{y:.2f} Z:{z:.2f} E:{e:.2f} Count {counts}")

    # -- heaters and messages --------------------------------------------------------

    def _set_temp(
        self, heater: Heater, args: str, now: float, *, wait: bool
    ) -> Job | None:
        given = words(args)
        value = given.get("S", given.get("R"))
        if value is not None:
            heater.set_target(value, now)
        if not wait:
            return None
        return self._wait_heat(heater, now, heating_only="S" in given)

    def _wait_heat(self, heater: Heater, now: float, *, heating_only: bool) -> Job:
        """M109/M190: report every second until the target is reached or M108 says stop."""
        self.cancel_wait = False
        report_at = now
        while not self.cancel_wait:
            heater.update(now)
            if heater.reached(heating_only=heating_only):
                return
            if now >= report_at:
                self._print(f" {self.temperatures(now)} W:?")
                report_at = now + 1.0
            now = yield min(report_at, max(heater.reach_time(), now))

    def _m105(self, args: str, now: float) -> None:
        self.custom_ok = "ok " + self.temperatures(now)

    def _m118(self, args: str, now: float) -> None:
        message = args.strip()
        prefix = ""
        for flag, value in (("E1", "echo:"), ("A1", "//")):
            if message.startswith(flag):
                prefix, message = value, message[len(flag) :].strip()
        self._print(prefix + message)


def _arc_length(
    start: list[float], end: list[float], given: dict[str, float], turn: int
) -> float:
    """Length of a G2/G3 arc in XY (I/J centre or R radius), with Z as a helix."""
    sx, sy, ex, ey = start[0], start[1], end[0], end[1]
    if "R" in given:
        radius = abs(given["R"]) or 1e-9
        chord = math.hypot(ex - sx, ey - sy)
        angle = 2 * math.asin(min(1.0, chord / (2 * radius)))
        if given["R"] < 0:
            angle = 2 * math.pi - angle
    else:
        cx, cy = sx + given.get("I", 0.0), sy + given.get("J", 0.0)
        radius = math.hypot(sx - cx, sy - cy)
        a0, a1 = math.atan2(sy - cy, sx - cx), math.atan2(ey - cy, ex - cx)
        angle = (a1 - a0) * turn % (2 * math.pi) or 2 * math.pi
    return math.hypot(radius * angle, end[2] - start[2])
