"""The analyser's slow path: one comment or command at a time, as the firmware
reads it (`Analyser` is made of this and the fast path of `blocks.py`).

Comments go to the thumbnail reader, the layer and object marks and the slicer's
notes. Commands other than the plain moves the fast path reads: arcs, homing,
dwells, firmware retraction, positions set by G92, units and modes, tools, and
the settings (M201, M203, M204, M205, M207, M220, M221, M566) and heaters that
change how later moves are timed. The methods work on the machine state the
`Analyser` holds; this class is never used alone.
"""

from __future__ import annotations

import math
import re

from jobs.analysis.arcs import center_from_radius, cut_arc
from jobs.analysis.limits import with_setting

_WORD = re.compile(rb"([A-Z])[ \t]*([-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+))")
_CODE = re.compile(rb"[ \t]*([GMT])[ \t]*([0-9]+)(?:\.([0-9]+))?")
#: The first word of every mark below and of a thumbnail's start (one test for
#: the many comments that are none of them).
_MARK_WORD = re.compile(r"\s*(?:thumbnail|layer|printing object)", re.I)
_LAYER_MARK = re.compile(r"^\s*(?:LAYER_CHANGE\b|LAYER:\s*-?\d+|layer \d+, Z ?=)", re.I)
_OBJECT_MARK = re.compile(
    r"^\s*printing object\s+(.+?)\s*(?:id:\d+\s+copy\s+\d+)?\s*$", re.I
)
_NAME_WORD = re.compile(rb"NAME=(\"[^\"]*\"|'[^']*'|\S+)", re.I)
_M486_NAME = re.compile(rb"\s*M486\s*A\s*(.+)$", re.I)
_EXCLUDE = b"EXCLUDE_OBJECT_DEFINE "
_AXES = "XYZE"
_MAX_OBJECTS = 1000
#: Tool numbers a file may use (T0 to T255); a higher one is not a tool.
MAX_TOOLS = 256


class Commands:
    """The slow path's methods, mixed into `Analyser`."""

    def comment(self, text: str, offset: int = 0) -> bool:
        """Read one comment (of the line at byte *offset*); True if it marks a new
        layer."""
        if self.thumbs.reading or _MARK_WORD.match(text):
            if self.thumbs.comment(text):
                return False
            if _LAYER_MARK.match(text):
                return True
            match = _OBJECT_MARK.match(text)
            if match:
                self._object(match.group(1), offset)
                return False
        self.notes.comment(text)
        return False

    def special(self, code: bytes, index: int, offset: int) -> None:
        """One command the fast path does not read, at command *index*."""
        self._index, self._offset_here = index, offset
        self.filament_marks_until(index + 1)
        if b"(" in code:
            code = _without_parentheses(code).strip()
            if not code:
                return
        label = _NAME_WORD.search(code) if code[:22].upper() == _EXCLUDE else None
        label = label or _M486_NAME.match(code)
        if label:  # Klipper's EXCLUDE_OBJECT_DEFINE NAME=..., Marlin's M486 A...
            self._object(
                label.group(1).strip(b"\"'").decode("utf-8", "replace"), offset
            )
            return
        self._command(code if code.isupper() else code.upper())

    def _object(self, name: str, offset: int) -> None:
        """An object's name, first seen at byte *offset* (objects are listed in the
        order the file names them)."""
        name = name.strip()[:200]
        if name not in self._objects and len(self._objects) < _MAX_OBJECTS:
            self._objects[name] = offset

    def _command(self, code: bytes) -> None:
        head = _CODE.match(code)
        if head is None:
            return  # GRBL `$` settings, RepRapFirmware `EXCLUDE_OBJECT...`, etc.
        letter, number = head.group(1), int(head.group(2))
        if letter == b"G":
            if number <= 3:
                self._move(number, code, head.end())
            elif number == 4:
                self._dwell(code)
            elif number == 90:
                self._absolute = True
                self._absolute_e = True
            elif number == 91:
                self._absolute = False
                self._absolute_e = False
            elif number == 92:
                self._set_position(code, head.end())
            elif number == 20:
                self._inches = True
            elif number == 21:
                self._inches = False
            elif number == 28:
                self._home(code, head.end())
            elif number in (10, 11) and not self.cnc:
                self._firmware_retract(retract=number == 10)
        elif letter == b"M":
            self._m_code(number, code, head.end())
        elif letter == b"T" and number < MAX_TOOLS:  # else not a tool anyone has
            self._tool = number
            self._tools.setdefault(number, None)

    def _words(self, code: bytes, start: int) -> dict[str, float]:
        words: dict[str, float] = {}
        for letter, value in _WORD.findall(code, start):
            try:
                words[letter.decode()] = float(value)
            except ValueError:
                continue
        return words

    def _move(self, number: int, code: bytes, start: int) -> None:
        words = self._words(code, start)
        scale = 25.4 if self._inches else 1.0
        if "F" in words and words["F"] > 0:
            self._feed = words["F"] * scale / 60.0
        pos = self._pos
        target = list(pos)
        for axis, letter in enumerate(_AXES):
            if letter in words:
                value = words[letter] * scale
                relative = not (self._absolute_e if axis == 3 else self._absolute)
                target[axis] = pos[axis] + value if relative else value
        if self.cnc:
            target[3] = pos[3]
        if number >= 2:
            self._arc(number, words, target, scale)
            return
        rapid = self.cnc and number == 0
        self._segment(target, rapid=rapid)

    def _segment(self, target: list[float], *, rapid: bool = False) -> None:
        pos = self._pos
        delta = (
            target[0] - pos[0],
            target[1] - pos[1],
            target[2] - pos[2],
            target[3] - pos[3],
        )
        if delta == (0.0, 0.0, 0.0, 0.0):
            return
        self._moves += 1
        de = delta[3]
        if de:
            self.add_filament(de * self._flow.get(self._tool, 1.0))
        if delta[2]:
            self._z_change = (self._index, self._offset_here)
        xyz = math.sqrt(delta[0] ** 2 + delta[1] ** 2 + delta[2] ** 2)
        cutting = (not rapid) if self.cnc else (de > 0 and xyz > 0)
        if cutting:
            self.result.print_distance += xyz
            self._include(pos)
            self._include(target)
            if not self.cnc:
                self._layer_check(target[2])
        else:
            self.result.travel_distance += xyz
        if self.cnc and not rapid and self._feed <= 0.0:
            rapid = True  # GRBL refuses G1 before any F; time it as a rapid
            if "a cutting move has no feed rate" not in self.result.notes:
                self.result.notes.append("a cutting move has no feed rate")
        feed = 1e9 if rapid else self._feed * self._speed_factor
        self.planner.move(self._index, delta, feed)
        if self.toolpath is not None:
            move = (self._index, pos, target, cutting, feed, self.feature)
            if self._chords is not None:
                self._chords.append(move)  # an arc's: drawn as one polyline
            else:
                self._draw_moves([move])
        self._pos = target

    def _arc(
        self, number: int, words: dict[str, float], target: list[float], scale: float
    ) -> None:
        """G2 (clockwise) or G3 in the XY plane, cut into chords as the firmware does."""
        start, clockwise = list(self._pos), number == 2
        if "R" in words:
            center = center_from_radius(
                start, target, words["R"] * scale, clockwise=clockwise
            )
        else:
            center = (
                start[0] + words.get("I", 0.0) * scale,
                start[1] + words.get("J", 0.0) * scale,
            )
        arc = cut_arc(
            start,
            target,
            center,
            clockwise=clockwise,
            segment=self.limits.arc_segment,
            tolerance=self.limits.arc_tolerance,
        )
        if self.cnc or target[3] > start[3]:
            for x, y in arc.extremes:
                self._include([x, y, start[2]])
                self._include([x, y, target[2]])
        self._chords = [] if self.toolpath is not None else None
        for point in arc.points:
            self._segment(point)
        chords, self._chords = self._chords, None
        if chords:
            self._draw_moves(chords)

    def _set_position(self, code: bytes, start: int) -> None:
        words = self._words(code, start)
        scale = 25.4 if self._inches else 1.0
        if not any(letter in words for letter in _AXES):
            self._pos = [0.0, 0.0, 0.0, 0.0]
            return
        for axis, letter in enumerate(_AXES):
            if letter in words:
                self._pos[axis] = words[letter] * scale

    def _home(self, code: bytes, start: int) -> None:
        """G28: the named axes (all without a name) end at 0; homing is not timed."""
        self.planner.flush()
        rest = code[start:]
        named = [axis for axis, letter in enumerate(b"XYZ") if letter in rest]
        for axis in named or (0, 1, 2):
            self._pos[axis] = 0.0

    def _dwell(self, code: bytes) -> None:
        words = self._words(code, 2)
        if self.cnc:
            seconds = words.get("P", 0.0)  # GRBL's P is seconds
        else:
            seconds = words.get("S", 0.0) + words.get("P", 0.0) / 1000.0
        self._wait(max(seconds, 0.0), heating=False)

    def _firmware_retract(self, *, retract: bool) -> None:
        limits = self.limits
        length = limits.retract_length * (-1 if retract else 1)
        speed = limits.retract_speed if retract else limits.recover_speed
        if bool(self._retracted) == retract:
            return
        self._retracted = limits.retract_length if retract else 0.0
        self.planner.move(self._index, (0.0, 0.0, 0.0, length), speed)

    def _m_code(self, number: int, code: bytes, start: int) -> None:
        if number == 82:
            self._absolute_e = True
        elif number == 83:
            self._absolute_e = False
        elif number in (104, 109, 140, 190, 116):
            self._heater(number, self._words(code, start))
        elif number in (201, 203, 204, 205, 207, 208, 566, 220, 221) and not (
            self.cnc and number != 220  # GRBL's limits are its $ settings
        ):
            self._setting(number, self._words(code, start))
        elif self.cnc and number in (3, 4):
            words = self._words(code, start)
            self.result.spindle_max = max(self.result.spindle_max, words.get("S", 0.0))
        elif number == 400:
            self.planner.flush()

    def _setting(self, number: int, words: dict[str, float]) -> None:
        if number == 220:
            if "S" in words and words["S"] > 0:
                self._speed_factor = words["S"] / 100.0
        elif number == 221:
            if "S" in words and words["S"] >= 0:
                tool = _tool(words, self._tool)
                if tool is not None:
                    self._flow[tool] = words["S"] / 100.0
        else:
            self.limits = with_setting(
                self.limits, number, words, firmware=self.firmware
            )
            self.planner.set_limits(self.limits)
            self.heaters.limits = self.limits

    def _heater(self, number: int, words: dict[str, float]) -> None:
        """Targets (M104, M140) and waits (M109, M190, M116) of the heater model."""
        if number in (109, 190, 116):
            self.planner.flush()  # the firmware waits once its moves are done
        now = self.clock.now
        if number == 116:
            self._wait(self.heaters.wait_all(now), heating=True)
            return
        tool = _tool(words, self._tool)
        if number not in (140, 190) and tool is None:
            return
        name = "bed" if number in (140, 190) else f"tool{tool}"
        self.heaters.set_target(name, words.get("S", words.get("R")), now)
        if number in (109, 190) and ("S" in words or "R" in words):
            self._wait(self.heaters.wait(name, now, either="R" in words), heating=True)


def _tool(words: dict[str, float], current: int) -> int | None:
    """The tool a command's T names (the current one without T); None for a number
    no machine has (each tool and heater is kept: T4000000000 would fill memory)."""
    value = words.get("T", current)
    if not 0 <= value < MAX_TOOLS:
        return None
    return int(value)


def _without_parentheses(code: bytes) -> bytes:
    out = bytearray()
    depth = 0
    for byte in code:
        if byte == 0x28:
            depth += 1
        elif byte == 0x29 and depth:
            depth -= 1
        elif not depth:
            out.append(byte)
    return bytes(out)
