"""Reading a G-code file once, as it streams by, into an `Analysis` (sans-IO).

    analyser = Analyser(limits, firmware="marlin")
    for chunk in chunks:            # any sizes; lines may straddle chunks
        analyser.feed(chunk)
    analysis = analyser.finish()

Per line: comments go to the slicer notes, the thumbnail reader and the layer and
object markers; commands are counted as the stream counts them, and moves go to
the planner (`planner.py`) with the machine state the firmware would have (units,
absolute or relative axes and E, feedrate, speed and flow factors, the active
tool). Settings commands in the file (M201, M203, M204, M205, M207, M220, M221,
M566) change the limits as the firmware would. Heater waits are timed by a simple
model (a steady rate toward the target) and kept apart from motion.

GRBL files (`firmware="grbl"`) are read as CNC: G0 at the machine's rapid rate,
arcs, inches, tools and spindle; no filament.
"""

from __future__ import annotations

import math
import re
from typing import TYPE_CHECKING

import numpy as np

from jobs.analysis.arcs import center_from_radius, cut_arc
from jobs.analysis.blocks import BLOCK_BYTES, read_block
from jobs.analysis.clock import Clock
from jobs.analysis.heaters import HeaterModel
from jobs.analysis.limits import Materials, MotionLimits, with_setting
from jobs.analysis.metadata import SlicerNotes
from jobs.analysis.planner import Planner
from jobs.analysis.result import Analysis, Layer, Timeline
from jobs.analysis.thumbnails import ThumbnailReader
from jobs.analysis.toolpath import ToolpathWriter

if TYPE_CHECKING:
    from typing import BinaryIO

    from jobs.analysis.thumbnails import Thumbnail

_WORD = re.compile(rb"([A-Z])[ \t]*([-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+))")
_CODE = re.compile(rb"[ \t]*([GMT])[ \t]*([0-9]+)(?:\.([0-9]+))?")
_LAYER_MARK = re.compile(r"^\s*(?:LAYER_CHANGE\b|LAYER:\s*-?\d+|layer \d+, Z ?=)", re.I)
_FEATURE_MARK = re.compile(r"^\s*(?:TYPE|FEATURE)\s*:\s*(\S.*?)\s*$", re.I)
_OBJECT_MARK = re.compile(
    r"^\s*printing object\s+(.+?)\s*(?:id:\d+\s+copy\s+\d+)?\s*$", re.I
)
_NAME_WORD = re.compile(rb"NAME=(\"[^\"]*\"|'[^']*'|\S+)", re.I)
_M486_NAME = re.compile(rb"\s*M486\s*A\s*(.+)$", re.I)
_EXCLUDE = b"EXCLUDE_OBJECT_DEFINE "
_AXES = "XYZE"
#: A layer needs at least this much Z above the last one (mm).
_LAYER_STEP = 1e-4
#: Z layers kept at most (a vase-mode file without markers climbs on every move).
_MAX_LAYERS = 100_000
_MAX_OBJECTS = 1000
#: A line longer than this (no line end in sight) is skipped, not held.
MAX_LINE_BYTES = 4 * BLOCK_BYTES


class Analyser:
    """Feeds on bytes, ends with an `Analysis`. One file per analyser."""

    def __init__(
        self,
        limits: MotionLimits | None = None,
        *,
        firmware: str = "marlin",
        materials: Materials | None = None,
        stride: int = 256,
        toolpath: BinaryIO | None = None,
    ) -> None:
        self.firmware = firmware
        self.cnc = firmware == "grbl"
        self.limits = limits or MotionLimits()
        self.materials = materials or Materials()
        self.notes = SlicerNotes()
        self.thumbs = ThumbnailReader()
        self.result = Analysis(kind="cnc" if self.cnc else "fff")
        self.timeline = Timeline(stride=stride)
        self.result.timeline = self.timeline
        self.clock = Clock(self.timeline)
        self.planner = Planner(self.limits, self.clock.timed)
        self._buffer = bytearray()
        self._skipping = False  # inside a line too long to hold
        self._offset = 0  # bytes before the next block
        self._offset_here = 0  # bytes before the line being read
        self._index = 0  # commands before the line being read
        # Machine state, in millimetres.
        self._pos = [0.0, 0.0, 0.0, 0.0]
        self._absolute = True
        self._absolute_e = True
        self._inches = False
        self._feed = 1500.0 / 60.0 if not self.cnc else 0.0
        self._speed_factor = 1.0
        self._flow: dict[int, float] = {}
        self._tool = 0
        self._filament: dict[int, float] = {}
        self._filament_total = 0.0
        self._retracted = 0.0
        self._z_layers: list[Layer] = []
        self._marked_layers: list[Layer] = []
        self._mark_pending = False
        self._layer_z = -math.inf
        self._z_change = (0, 0)  # command and offset of the last move that changed Z
        self._bbox_min = [math.inf, math.inf, math.inf]
        self._bbox_max = [-math.inf, -math.inf, -math.inf]
        self._objects: dict[str, int] = {}
        self.heaters = HeaterModel(self.limits)
        self._moves = 0
        self._tools: dict[int, None] = {}
        # The preview's geometry (toolpath.py), when asked for: the feature being
        # printed, and where each layer's records start (one list per way of
        # finding layers; resolved once the moves that follow the start are written).
        self.toolpath = ToolpathWriter(toolpath) if toolpath is not None else None
        self.feature = 0
        self._layer_bytes: dict[int, list[int]] = {
            id(self._z_layers): [],
            id(self._marked_layers): [],
        }
        self._unplaced: list[tuple[list[int], int]] = []
        self._chords: list[tuple] | None = None  # an arc's moves, while it is cut

    # -- bytes in ---------------------------------------------------------------

    def feed(self, data: bytes) -> None:
        """Read *data*, the next bytes of the file."""
        if self._skipping:
            end = data.find(b"\n")
            if end < 0:
                self._offset += len(data)
                return
            self._offset += end + 1
            data, self._skipping = data[end + 1 :], False
        self._buffer += data
        if len(self._buffer) < BLOCK_BYTES:
            return
        cut = self._buffer.rfind(b"\n") + 1
        if cut:
            block, self._buffer = bytes(self._buffer[:cut]), self._buffer[cut:]
            read_block(self, block)
        elif len(self._buffer) > MAX_LINE_BYTES:
            # One line longer than any G-code line: skip it, never hold it whole.
            self._offset += len(self._buffer)
            self._buffer = bytearray()
            self._skipping = True
            note = f"a line over {MAX_LINE_BYTES >> 20} MB was skipped"
            if note not in self.result.notes:
                self.result.notes.append(note)

    def finish(self) -> Analysis:
        """End of file: time what is queued and return the analysis."""
        if self._buffer:
            tail = bytes(self._buffer)
            self._buffer = bytearray()
            read_block(self, tail if tail.endswith(b"\n") else tail + b"\n")
        self.planner.flush()
        self.thumbs.finish()
        result = self.result
        result.commands = self._index
        result.motion_seconds = round(self.clock.motion, 3)
        result.heating_seconds = round(self.clock.heating, 3)
        self.filament_marks_until(self._index + 1)
        self.clock.finish(self._index)
        layers = self._marked_layers or self._z_layers
        result.layers = [layer for layer in layers if layer.z != -math.inf]
        if self.toolpath is not None:
            self.place_layers()
            starts = self._layer_bytes[id(layers)]
            starts = [
                b
                for b, layer in zip(starts, layers, strict=False)
                if layer.z != -math.inf
            ]
            result.toolpath = {
                "features": self.toolpath.features,
                "bytes": self.toolpath.written,
                "points": self.toolpath.points,
                "layers": self.toolpath.finish(starts, result.layers),
            }
            if self.cnc and self.toolpath.written:
                # A CNC job has no layers: its preview is the whole toolpath at once.
                result.toolpath["layers"] = [[0, self.toolpath.written]]
        if self._bbox_min[0] != math.inf:
            result.bbox = [
                [round(value, 3) for value in self._bbox_min],
                [round(value, 3) for value in self._bbox_max],
            ]
        result.print_distance = round(result.print_distance, 2)
        result.travel_distance = round(result.travel_distance, 2)
        result.dwell_seconds = round(result.dwell_seconds, 3)
        result.objects = sorted(self._objects, key=self._objects.__getitem__)
        result.tools = sorted(self._tools)
        if not self.cnc:
            self._filament_facts(result)
        result.slicer = self.notes.as_dict()
        result.notes.extend(self.thumbs.notes)
        if self._moves == 0:
            result.notes.append("the file has no moves: nothing to time or draw")
        return result

    @property
    def pictures(self) -> list[Thumbnail]:
        return self.thumbs.pictures

    def draw(
        self,
        tags: np.ndarray,
        starts: np.ndarray,
        ends: np.ndarray,
        drawn: np.ndarray,
        speeds: np.ndarray,
        features: np.ndarray,
    ) -> None:
        """Moves for the preview (a no-op unless a toolpath sink was given)."""
        if self.toolpath is None:
            return
        self.toolpath.add(tags, starts, ends, drawn, speeds, features)
        self.place_layers()

    def _draw_moves(self, moves: list[tuple]) -> None:
        """Moves of the slow path (index, start, end, drawn, speed, feature)."""
        index, starts, ends, drawn, speeds, features = zip(*moves, strict=True)
        self.draw(
            np.array(index), np.array(starts), np.array(ends),
            np.array(drawn), np.array(speeds), np.array(features),
        )  # fmt: skip

    def place_layers(self) -> None:
        """Byte offsets of the layers begun since the last moves were drawn."""
        if self.toolpath is None:
            return
        for starts, line in self._unplaced:
            starts.append(self.toolpath.offset_of(line))
        self._unplaced.clear()

    def feature_of(self, text: str) -> int | None:
        """The feature a `;TYPE:` / `;FEATURE:` comment starts, else None."""
        match = _FEATURE_MARK.match(text)
        if match is None:
            return None
        if self.toolpath is None:
            return 0
        return self.toolpath.feature(match.group(1))

    def add_picture(self, kind: str, data: bytes) -> None:
        """A thumbnail stored apart from the G-code (a binary G-code block)."""
        self.thumbs.add(kind, data)

    def _filament_facts(self, result: Analysis) -> None:
        count = max(self._filament, default=-1) + 1
        result.filament_mm = [
            round(self._filament.get(i, 0.0), 2) for i in range(count)
        ]
        notes = self.notes.values
        diameter = notes.get("filament_diameter") or self.materials.diameter
        density = notes.get("filament_density") or self.materials.density
        volume = self._filament_total * math.pi * (diameter / 2) ** 2
        weight = volume * density / 1000.0
        result.filament_volume_mm3 = round(volume, 1)
        result.filament_weight_g = round(weight, 2)

    # -- time ------------------------------------------------------------------

    def filament_marks_until(
        self,
        end: int,
        tags: np.ndarray | None = None,
        pushed: np.ndarray | None = None,
    ) -> None:
        """Filament before each marked command below *end*: read from *pushed* (the
        filament before each move of *tags*, from the last total) where a move of
        the run is at or after the mark, else the total now."""
        stride, marks = self.timeline.stride, self.timeline.filament
        while len(marks) * stride < end:
            mark = len(marks) * stride
            value = self._filament_total
            if tags is not None and pushed is not None and len(tags):
                at = int(np.searchsorted(tags, mark))
                if at < len(tags):
                    value = float(pushed[at])
            marks.append(round(value, 2))
        self.timeline.thin()

    def _wait(self, seconds: float, *, heating: bool) -> None:
        """The machine stands still: queued moves end first (the firmware syncs)."""
        self.planner.flush()
        if seconds <= 0.0:
            return
        if heating:
            self.clock.heat(self._index, seconds)
        else:
            self.result.dwell_seconds += seconds
            self.planner.pause(self._index, seconds)

    # -- lines (the slow path: comments and commands other than G0, G1, G92) ----

    def comment(self, text: str, offset: int = 0) -> bool:
        """Read one comment (of the line at byte *offset*); True if it marks a new
        layer."""
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
        elif letter == b"T":
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

    # -- moves -------------------------------------------------------------------

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

    def add_filament(self, millimetres: float) -> None:
        self._filament[self._tool] = self._filament.get(self._tool, 0.0) + millimetres
        self._filament_total += millimetres

    def _include(self, point: list[float]) -> None:
        low, high = self._bbox_min, self._bbox_max
        for axis in range(3):
            value = point[axis]
            if value < low[axis]:
                low[axis] = value
            if value > high[axis]:
                high[axis] = value

    def include_box(self, low: np.ndarray, high: np.ndarray) -> None:
        self._include([float(value) for value in low])
        self._include([float(value) for value in high])

    def _layer_check(self, z: float) -> None:
        """An extruding move at *z*: a new layer if it is above the last one."""
        if self._mark_pending:
            self._mark_pending = False
            self._new_layer(self._marked_layers, z)
        if z > self._layer_z + _LAYER_STEP:
            self._layer_z = z
            self._new_layer(self._z_layers, z)

    def _new_layer(self, layers: list[Layer], z: float) -> None:
        self.new_layer(layers, z, self._z_change, (self._index, self._offset_here))

    def new_layer(
        self,
        layers: list[Layer],
        z: float,
        z_change: tuple[int, int],
        here: tuple[int, int],
    ) -> None:
        """A layer at *z* starting at the last Z change, or *here* if that change
        belongs to the layer before.

        Once the slicer marks layers, its marks win (`finish`): the layers found by
        height are dropped and no longer kept, so a file holds one list of them."""
        if layers is self._z_layers and self._marked_layers:
            if layers:
                layers.clear()
                self._layer_bytes[id(layers)].clear()
            return
        if len(layers) >= _MAX_LAYERS:
            return
        line, offset = z_change
        if layers and line <= layers[-1].line:
            line, offset = here
        layer = Layer(round(z, 4), line, offset)
        layers.append(layer)
        if self.toolpath is not None:
            self._unplaced.append((self._layer_bytes[id(layers)], line))
        self.clock.layer_starts(layer)

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

    # -- settings and heaters ----------------------------------------------------

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
                tool = int(words.get("T", self._tool))
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
        name = (
            "bed" if number in (140, 190) else f"tool{int(words.get('T', self._tool))}"
        )
        self.heaters.set_target(name, words.get("S", words.get("R")), now)
        if number in (109, 190) and ("S" in words or "R" in words):
            self._wait(self.heaters.wait(name, now, either="R" in words), heating=True)


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
