"""GRBL 1.1's G-code interpreter without time: a cleaned line in, error code or actions out.

Actions are tuples the firmware model plays in order:
("move", target, seconds at 100 %, rapid), ("sync",), ("dwell", seconds),
("eeprom",), ("pause",), ("end",), ("probe",).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from printers.simulator._motion import distance

__all__ = ["Block", "GcodeState", "parse_block"]

_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)")
#: G codes (value x 10) and their modal group; "nonmodal" is GRBL's group 0.
_G_GROUPS = {
    **dict.fromkeys((0, 10, 20, 30, 382, 383, 384, 385, 800), "motion"),
    **dict.fromkeys((170, 180, 190), "plane"),
    **dict.fromkeys((900, 910), "distance"),
    911: "arc_distance",
    **dict.fromkeys((930, 940), "feed_mode"),
    **dict.fromkeys((200, 210), "units"),
    400: "cutter",
    **dict.fromkeys((431, 490), "tool_length"),
    **dict.fromkeys((540, 550, 560, 570, 580, 590), "coord"),
    610: "path",
    **dict.fromkeys((40, 100, 280, 281, 300, 301, 530, 920, 921), "nonmodal"),
}
_M_GROUPS = {
    **dict.fromkeys((0, 1, 2, 30), "stop"),
    **dict.fromkeys((3, 4, 5), "spindle"),
    **dict.fromkeys((7, 8, 9), "coolant"),
}
_PLANE_AXES = {170: (0, 1), 180: (2, 0), 190: (1, 2)}
_FEED_MOTIONS = (10, 20, 30, 382, 383, 384, 385)
_AXIS_NONMODAL = (100, 280, 300, 920)
_JOG_GROUPS = {"units", "distance", "nonmodal"}
AXES = "XYZ"


@dataclass
class Block:
    """One parsed line: G codes by modal group, M codes by group, other words."""

    g: dict[str, int] = field(default_factory=dict)
    m: dict[str, int] = field(default_factory=dict)
    words: dict[str, float] = field(default_factory=dict)


def parse_block(line: str) -> Block | int:
    """Parse a cleaned line (upper case, no spaces, no comments) or return GRBL's error."""
    block = Block()
    pos, size = 0, len(line)
    while pos < size:
        letter = line[pos]
        if not "A" <= letter <= "Z":
            return 1  # expected command letter
        number = _NUMBER.match(line, pos + 1)
        if number is None:
            return 2  # bad number format
        value = float(number[0])
        pos = number.end()
        error = _add_word(block, letter, value)
        if error:
            return error
    return block


def _add_word(block: Block, letter: str, value: float) -> int:
    if letter == "G":
        code = round(value * 10)
        group = _G_GROUPS.get(code)
        if group is None:
            return 23 if code % 10 and code - code % 10 in _G_GROUPS else 20
        if group in block.g:
            return 21  # modal group violation
        block.g[group] = code
    elif letter == "M":
        group = _M_GROUPS.get(int(value)) if value == int(value) else None
        if group is None:
            return 20
        if group in block.m:
            return 21
        block.m[group] = int(value)
    elif letter in "FIJKLNPRSTXYZ":
        if letter in block.words:
            return 25  # word repeated
        block.words[letter] = value
    else:
        return 20  # unsupported command
    return 0


class GcodeState:
    """The parser state `$G` reports, plus positions and work offsets (`$#`)."""

    def __init__(self, max_rates: tuple[float, float, float]) -> None:
        self.max_rates = max_rates
        self.position = [0.0, 0.0, 0.0]
        self.offsets = [[0.0, 0.0, 0.0] for _ in range(6)]
        self.g28 = [0.0, 0.0, 0.0]
        self.g30 = [0.0, 0.0, 0.0]
        self.reset_modes()

    def reset_modes(self) -> None:
        """gc_init after a reset: G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0, and no G92
        offset (GRBL 1.1 zeroes its whole parser state; the stored G54-G59 offsets
        and the position stay)."""
        self.g92 = [0.0, 0.0, 0.0]
        self.motion, self.coord, self.plane, self.units = 0, 0, 170, 210
        self.distance, self.feed_mode = 900, 940
        self.spindle, self.coolant = 5, set()
        self.tool, self.feed, self.speed = 0, 0.0, 0.0

    @property
    def unit(self) -> float:
        return 25.4 if self.units == 200 else 1.0

    def work_offset(self) -> list[float]:
        """WCO: machine position minus work position."""
        return [c + g for c, g in zip(self.offsets[self.coord], self.g92, strict=True)]

    def modes(self) -> str:
        """`$G`'s report, without brackets."""
        motion = f"G{self.motion // 10}" + (
            f".{self.motion % 10}" if self.motion % 10 else ""
        )
        coolant = " ".join(f"M{c}" for c in sorted(self.coolant)) or "M9"
        return (
            f"GC:{motion} G{54 + self.coord} G{self.plane // 10} G{self.units // 10} "
            f"G{self.distance // 10} G{self.feed_mode // 10} M{self.spindle} {coolant} "
            f"T{self.tool} F{self.feed / self.unit:.0f} S{self.speed:.0f}"
        )

    def execute(self, line: str) -> int | list[tuple]:
        """Run one G-code line against the state: GRBL's error code, or the actions."""
        block = parse_block(line)
        if isinstance(block, int):
            return block
        error = self._validate(block)
        if error:
            return error
        return self._apply(block)

    def jog(self, line: str) -> int | tuple:
        """`$J=` line (after the `=`): a move that leaves the modal state alone."""
        block = parse_block(line)
        if isinstance(block, int):
            return block
        words = block.words
        if block.m or set(block.g) - _JOG_GROUPS or set(words) - set("XYZFN"):
            return 16  # invalid jog command
        if block.g.get("nonmodal", 530) != 530 or not set(words) & set(AXES):
            return 16
        if "F" not in words:
            return 22
        saved = (self.units, self.distance)
        self.units = block.g.get("units", self.units)
        self.distance = block.g.get("distance", self.distance)
        target = self._target(words, machine="nonmodal" in block.g)
        feed = words["F"] * self.unit
        self.units, self.distance = saved
        seconds = distance(tuple(self.position), tuple(target)) / feed * 60.0
        self.position = target
        return ("move", tuple(target), seconds, False)

    # -- checks -------------------------------------------------------------------

    def _validate(self, block: Block) -> int:
        words, g = block.words, block.g
        if any(words.get(k, 0.0) < 0 for k in "FNPST"):
            return 4  # negative value
        if words.get("N", 0) > 9999999:
            return 27
        if words.get("T", 0) > 255:
            return 38
        nonmodal = g.get("nonmodal")
        axis_words = any(a in words for a in AXES)
        if "motion" in g and nonmodal in _AXIS_NONMODAL and axis_words:
            return 24  # axis command conflict
        error = self._check_nonmodal(nonmodal, words)
        if error:
            return error
        motion = g.get("motion", self.motion)
        moving = nonmodal not in _AXIS_NONMODAL and (axis_words or "motion" in g)
        if moving:
            error = self._check_motion(block, motion, axis_words=axis_words)
        if nonmodal == 530 and motion not in (0, 10):
            return 30
        return error or self._check_unused(block, motion if moving else None)

    def _check_nonmodal(self, nonmodal: int | None, words: dict[str, float]) -> int:
        if nonmodal == 40 and "P" not in words:
            return 28  # value word missing
        if nonmodal == 100:
            if "L" not in words or "P" not in words:
                return 28
            if words["L"] not in (2, 20):
                return 20
            if words["P"] != int(words["P"]) or not 0 <= words["P"] <= 6:
                return 29  # unsupported coordinate system
        return 0

    def _check_motion(self, block: Block, motion: int, *, axis_words: bool) -> int:
        words = block.words
        if motion == 800:
            return 31 if axis_words else 0
        if motion in _FEED_MOTIONS:
            inverse = block.g.get("feed_mode", self.feed_mode) == 930
            if "F" not in words and (inverse or self.feed <= 0):
                return 22  # undefined feed rate
        if motion in (20, 30):
            plane = _PLANE_AXES[block.g.get("plane", self.plane)]
            if not axis_words:
                return 26
            if not any(AXES[i] in words for i in plane):
                return 32  # no axis words in plane
            offsets = {"IJK"[i] for i in plane}
            if "R" not in words and not offsets & set(words):
                return 35  # no offsets in plane
        return 0

    def _check_unused(self, block: Block, motion: int | None) -> int:
        words = block.words
        nonmodal = block.g.get("nonmodal")
        used = set("FNSTXYZ")
        if nonmodal in (40, 100):
            used |= {"P"}
        if nonmodal == 100:
            used |= {"L"}
        if motion in (20, 30):
            used |= set("IJKR")
        return 36 if set(words) - used else 0

    # -- applying -----------------------------------------------------------------

    def _apply(self, block: Block) -> list[tuple]:
        g, m, words = block.g, block.m, block.words
        actions: list[tuple] = []
        self.feed_mode = g.get("feed_mode", self.feed_mode)
        self.units = g.get("units", self.units)
        if "F" in words:
            self.feed = words["F"] * (1.0 if self.feed_mode == 930 else self.unit)
        self.speed = words.get("S", self.speed)
        self.tool = int(words.get("T", self.tool))
        self._apply_machine_modes(m, actions)
        if g.get("nonmodal") == 40:
            actions += [("sync",), ("dwell", words["P"])]
        self.plane = g.get("plane", self.plane)
        self.distance = g.get("distance", self.distance)
        if "coord" in g:
            self.coord = (g["coord"] - 540) // 10
        self._apply_nonmodal(g.get("nonmodal"), words, actions)
        moving = g.get("nonmodal") not in _AXIS_NONMODAL
        self.motion = g.get("motion", self.motion)
        if moving and any(a in words for a in AXES):
            self._apply_motion(block, actions)
        self._apply_program_flow(m.get("stop"), actions)
        return actions

    def _apply_machine_modes(self, m: dict[str, int], actions: list[tuple]) -> None:
        """Spindle and coolant changes wait for the planner to empty (spindle_sync)."""
        spindle = m.get("spindle", self.spindle)
        coolant = self.coolant
        if "coolant" in m:
            coolant = set() if m["coolant"] == 9 else coolant | {m["coolant"]}
        if spindle != self.spindle or coolant != self.coolant:
            actions.append(("sync",))
        self.spindle, self.coolant = spindle, coolant

    def _apply_nonmodal(
        self, nonmodal: int | None, words: dict[str, float], actions: list[tuple]
    ) -> None:
        if nonmodal == 100:
            system = int(words["P"]) - 1 if words["P"] else self.coord
            for i, axis in enumerate(AXES):
                if axis in words:
                    value = words[axis] * self.unit
                    if words["L"] == 20:
                        value = self.position[i] - self.g92[i] - value
                    self.offsets[system][i] = value
            # GRBL empties the planner before it writes EEPROM.
            actions += [("sync",), ("eeprom",)]
        elif nonmodal in (280, 300):
            if any(a in words for a in AXES):
                self._rapid_to(self._target(words, machine=False), actions)
            self._rapid_to(list(self.g28 if nonmodal == 280 else self.g30), actions)
        elif nonmodal in (281, 301):
            stored = self.g28 if nonmodal == 281 else self.g30
            stored[:] = self.position
            actions += [("sync",), ("eeprom",)]
        elif nonmodal == 920:
            for i, axis in enumerate(AXES):
                if axis in words:
                    offset = self.offsets[self.coord][i]
                    self.g92[i] = self.position[i] - offset - words[axis] * self.unit
        elif nonmodal == 921:
            self.g92 = [0.0, 0.0, 0.0]

    def _apply_motion(self, block: Block, actions: list[tuple]) -> None:
        motion = self.motion
        if motion == 800:
            return
        machine = block.g.get("nonmodal") == 530
        target = self._target(block.words, machine=machine)
        if motion == 0:
            self._rapid_to(target, actions)
            return
        length = distance(tuple(self.position), tuple(target))
        if motion in (20, 30):
            length = self._arc_length(target, block.words, 1 if motion == 30 else -1)
        if self.feed_mode == 930:
            seconds = 60.0 / block.words["F"]
        else:
            seconds = length / self.feed * 60.0
        probe = motion >= 382
        if probe:
            actions.append(("sync",))
        actions.append(("move", tuple(target), seconds, False))
        if probe:
            actions += [("sync",), ("probe",)]
        self.position = target

    def _apply_program_flow(self, stop: int | None, actions: list[tuple]) -> None:
        if stop is None:
            return
        actions.append(("sync",))
        if stop in (0, 1):
            actions.append(("pause",))
            return
        self.motion, self.coord, self.plane = 10, 0, 170
        self.distance, self.feed_mode = 900, 940
        self.spindle, self.coolant = 5, set()
        actions.append(("end",))

    def _rapid_to(self, target: list[float], actions: list[tuple]) -> None:
        moved = [i for i in range(3) if target[i] != self.position[i]]
        if moved:
            rate = min(self.max_rates[i] for i in moved)
            seconds = distance(tuple(self.position), tuple(target)) / rate * 60.0
            actions.append(("move", tuple(target), seconds, True))
        self.position = target

    def _target(self, words: dict[str, float], *, machine: bool) -> list[float]:
        target = list(self.position)
        offset = self.work_offset()
        for i, axis in enumerate(AXES):
            if axis in words:
                value = words[axis] * self.unit
                if machine:
                    target[i] = value
                elif self.distance == 910:
                    target[i] += value
                else:
                    target[i] = value + offset[i]
        return target

    def _arc_length(
        self, target: list[float], words: dict[str, float], turn: int
    ) -> float:
        a, b = _PLANE_AXES[self.plane]
        start = self.position
        if "R" in words:
            radius = abs(words["R"] * self.unit) or 1e-9
            chord = math.hypot(target[a] - start[a], target[b] - start[b])
            angle = 2 * math.asin(min(1.0, chord / (2 * radius)))
            if words["R"] < 0:
                angle = 2 * math.pi - angle
        else:
            ca = start[a] + words.get("IJK"[a], 0.0) * self.unit
            cb = start[b] + words.get("IJK"[b], 0.0) * self.unit
            radius = math.hypot(start[a] - ca, start[b] - cb)
            a0 = math.atan2(start[b] - cb, start[a] - ca)
            a1 = math.atan2(target[b] - cb, target[a] - ca)
            angle = (a1 - a0) * turn % (2 * math.pi) or 2 * math.pi
        linear = 3 - a - b
        return math.hypot(radius * angle, target[linear] - start[linear])
