"""A machine's motion limits, as its firmware holds them before a file changes them.

The analyser starts from a printer's profile (`MotionLimits.from_profile`) and lets
the file override it as the firmware would (M201, M203, M204, M205, M566, M220).
Units are millimetres and seconds throughout; axes are X, Y, Z, E in that order.

Defaults are Marlin 2's (`Configuration.h`, junction deviation on, classic jerk off);
`GRBL_DEFAULTS` are GRBL 1.1's `$110..$122` and `$11`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

Axes = tuple[float, float, float, float]


class BadProfile(ValueError):
    """A motion profile value is missing its meaning (the message names the key)."""


@dataclass(frozen=True, slots=True)
class MotionLimits:
    """What the planner may do: per-axis caps and the accelerations of each move kind."""

    #: mm/s per axis (M203; RepRapFirmware M203 is mm/min, converted by the parser).
    max_feedrate: Axes = (300.0, 300.0, 5.0, 25.0)
    #: mm/s² per axis (M201).
    max_acceleration: Axes = (3000.0, 3000.0, 100.0, 10000.0)
    #: mm/s² for printing moves (M204 P), E-only moves (M204 R) and travel (M204 T).
    print_acceleration: float = 3000.0
    retract_acceleration: float = 3000.0
    travel_acceleration: float = 3000.0
    #: Marlin 2's junction deviation in mm (M205 J); used unless `classic_jerk`.
    junction_deviation: float = 0.013
    #: mm/s an axis may change speed at once (M205 X Y Z E, M566).
    jerk: Axes = (10.0, 10.0, 0.3, 5.0)
    #: Older Marlin, Prusa firmware and RepRapFirmware corner by jerk, not deviation.
    classic_jerk: bool = False
    #: M205 S and T: slowest printing and travel feedrate, mm/s.
    min_feedrate: float = 0.0
    min_travel_feedrate: float = 0.0
    #: Firmware retraction (G10/G11, M207/M208): length in mm and speeds in mm/s.
    retract_length: float = 3.0
    retract_speed: float = 45.0
    recover_speed: float = 8.0
    #: The simple heater model: °C per second up (and down), and the room.
    hotend_heat_rate: float = 2.0
    bed_heat_rate: float = 0.6
    cool_rate: float = 0.5
    ambient: float = 25.0
    #: Arcs are cut into chords no longer than this (Marlin's MAX_ARC_SEGMENT_MM).
    arc_segment: float = 1.0
    #: GRBL cuts arcs by a tolerance instead ($12, mm); 0 = use `arc_segment`.
    arc_tolerance: float = 0.0

    @classmethod
    def from_profile(
        cls, profile: dict[str, Any] | None, *, base: MotionLimits | None = None
    ) -> MotionLimits:
        """Limits from a printer's stored profile: any subset of the field names.

        Axis fields take a list of four numbers (X, Y, Z, E); every number must be
        finite and not negative. An unknown key or a bad value raises BadProfile.
        """
        limits = base or MotionLimits()
        if not profile:
            return limits
        known = {item.name: item for item in fields(cls)}
        changes: dict[str, Any] = {}
        for key, value in profile.items():
            if key not in known:
                raise BadProfile(f"{key!r} is not a motion setting")
            current = getattr(limits, key)
            if isinstance(current, bool):
                if not isinstance(value, bool):
                    raise BadProfile(f"{key}: true or false, not {value!r}")
                changes[key] = value
            elif isinstance(current, tuple):
                if not isinstance(value, (list, tuple)) or len(value) != 4:
                    raise BadProfile(f"{key}: four numbers for X, Y, Z and E")
                changes[key] = tuple(_number(key, item) for item in value)
            else:
                changes[key] = _number(key, value)
        return replace(limits, **changes)

    def as_profile(self) -> dict[str, Any]:
        """The limits as a stored profile (lists for the axes)."""
        return {
            key: list(value) if isinstance(value, tuple) else value
            for key, value in asdict(self).items()
        }


def _number(key: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise BadProfile(f"{key}: a number, not {value!r}")
    number = float(value)
    if not math.isfinite(number) or number < 0:
        raise BadProfile(f"{key}: {value!r} must be a finite number, 0 or more")
    return number


MARLIN_DEFAULTS = MotionLimits()

#: GRBL 1.1 defaults: $110-$112 = 500 mm/min, $120-$122 = 10 mm/s², $11 = 0.010 mm,
#: $12 = 0.002 mm. GRBL has one acceleration per axis and no print/travel split.
GRBL_DEFAULTS = MotionLimits(
    max_feedrate=(500 / 60, 500 / 60, 500 / 60, 0.0),
    max_acceleration=(10.0, 10.0, 10.0, 0.0),
    print_acceleration=1e9,
    retract_acceleration=1e9,
    travel_acceleration=1e9,
    junction_deviation=0.01,
    jerk=(0.0, 0.0, 0.0, 0.0),
    arc_tolerance=0.002,
)

#: RepRapFirmware corners by jerk (M566, mm/min in the file).
REPRAP_DEFAULTS = replace(
    MotionLimits(), classic_jerk=True, jerk=(15.0, 15.0, 0.6, 20.0)
)


def defaults_for(firmware: str) -> MotionLimits:
    """The firmware's own limits before any profile (`Printer.firmware` values)."""
    return {"grbl": GRBL_DEFAULTS, "reprap": REPRAP_DEFAULTS}.get(
        firmware, MARLIN_DEFAULTS
    )


@dataclass(frozen=True, slots=True)
class Materials:
    """Filament facts for weight: diameter in mm and density in g/cm³ (a file's own
    values win: the slicer knew the spool)."""

    diameter: float = 1.75
    density: float = 1.24


def with_setting(
    limits: MotionLimits, number: int, words: dict[str, float], *, firmware: str
) -> MotionLimits:
    """*limits* after the file's M201, M203, M204, M205, M207, M208 or M566 *number*
    with its *words*, as the firmware reads them; unchanged if a value is not a
    finite number of 0 or more."""
    per_minute = 1 / 60.0 if firmware == "reprap" else 1.0  # RRF's M203 is mm/min

    def axes(current: Axes, factor: float = 1.0) -> Axes:
        return tuple(  # type: ignore[return-value]
            words[letter] * factor if letter in words else current[axis]
            for axis, letter in enumerate("XYZE")
        )

    changes: dict[str, object] = {}
    if number == 201:
        changes["max_acceleration"] = axes(limits.max_acceleration)
    elif number == 203:
        changes["max_feedrate"] = axes(limits.max_feedrate, per_minute)
    elif number == 204:
        if "S" in words:  # Marlin's legacy S: printing and travel alike
            changes["print_acceleration"] = changes["travel_acceleration"] = words["S"]
        for letter, name in (
            ("P", "print_acceleration"),
            ("R", "retract_acceleration"),
            ("T", "travel_acceleration"),
        ):
            if letter in words:
                changes[name] = words[letter]
    elif number == 205:
        changes["jerk"] = axes(limits.jerk)
        for letter, name in (
            ("J", "junction_deviation"),
            ("S", "min_feedrate"),
            ("T", "min_travel_feedrate"),
        ):
            if letter in words:
                changes[name] = words[letter]
    elif number == 566:
        changes["jerk"] = axes(limits.jerk, 1 / 60.0)  # mm/min
    elif number == 207:
        if "S" in words:
            changes["retract_length"] = words["S"]
        if "F" in words:
            changes["retract_speed"] = words["F"] / 60.0
    elif number == 208 and "F" in words:
        changes["recover_speed"] = words["F"] / 60.0
    values = [
        value
        for change in changes.values()
        for value in (change if isinstance(change, tuple) else (change,))
    ]
    if not all(isinstance(v, float) and math.isfinite(v) and v >= 0 for v in values):
        return limits
    return replace(limits, **changes)  # type: ignore[arg-type]
