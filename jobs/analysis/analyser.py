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
model (a steady rate toward the target) and kept apart from motion. Plain moves
are read a block at a time (`blocks.py`), the rest one line at a time
(`commands.py`); this module holds the machine state both share.

GRBL files (`firmware="grbl"`) are read as CNC: G0 at the machine's rapid rate,
arcs, inches, tools and spindle; no filament.
"""

from __future__ import annotations

import math
import re
from typing import TYPE_CHECKING

import numpy as np

from jobs.analysis.blocks import BLOCK_BYTES, read_block
from jobs.analysis.clock import Clock
from jobs.analysis.commands import Commands
from jobs.analysis.heaters import HeaterModel
from jobs.analysis.limits import Materials, MotionLimits
from jobs.analysis.metadata import SlicerNotes
from jobs.analysis.planner import Planner
from jobs.analysis.result import Analysis, Layer, Timeline
from jobs.analysis.thumbnails import ThumbnailReader
from jobs.analysis.toolpath import ToolpathWriter

if TYPE_CHECKING:
    from collections.abc import Sequence
    from typing import BinaryIO

    from jobs.analysis.thumbnails import Thumbnail

_FEATURE_MARK = re.compile(r"^\s*(?:TYPE|FEATURE)\s*:\s*(\S.*?)\s*$", re.I)
#: A layer needs at least this much Z above the last one (mm).
_LAYER_STEP = 1e-4
#: Z layers kept at most (a vase-mode file without markers climbs on every move).
_MAX_LAYERS = 100_000
_MAX_OBJECTS = 1000
#: A line longer than this (no line end in sight) is skipped, not held.
MAX_LINE_BYTES = 4 * BLOCK_BYTES


class Analyser(Commands):
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
        #: Comments read before that change nothing when read again (the fast path
        #: skips them): the feature each starts, or -1 for none.
        self.known_comments: dict[bytes, int] = {}
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
            if self.toolpath.full:
                result.notes.append(
                    "the preview draws the first 256 MB of the toolpath only"
                )
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

    # -- the machine's state, shared by both paths --------------------------------

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

    def include_box(self, low: Sequence[float], high: Sequence[float]) -> None:
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
