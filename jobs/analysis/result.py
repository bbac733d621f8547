"""What an analysis found, and the lookups progress needs (time and filament by line).

`Analysis` is plain data: it goes to JSON for the database and the API and comes
back with `Analysis.from_dict`. Lines are command indexes: the count of commands
before a line, as the stream counts them (`jobs.gcode.iter_commands`), so a job's
`lines_acked` is directly a place in the timeline.
"""

from __future__ import annotations

from bisect import bisect_right
from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass(slots=True)
class Layer:
    """One layer: its Z, the command and byte offset it starts at, and when (s).

    The offset is in the G-code text the analyser read: for a binary G-code file,
    its decoded text (the command index is the same either way).
    """

    z: float
    line: int
    offset: int
    time: float = 0.0


#: The most marks a timeline keeps (`Timeline.thin`).
MAX_MARKS = 32_768


@dataclass(slots=True)
class Timeline:
    """Cumulative seconds and filament at every *stride*-th command.

    `seconds[k]` is the estimated time before command `k * stride` runs (motion and
    heating), `heating[k]` the heating share of it, `filament[k]` the filament (mm,
    all extruders) pushed before it. Between two marks the figure is interpolated:
    a stride is a few hundred commands, a few seconds of printing.
    """

    stride: int = 256
    seconds: list[float] = field(default_factory=list)
    heating: list[float] = field(default_factory=list)
    filament: list[float] = field(default_factory=list)

    def thin(self) -> None:
        """Past `MAX_MARKS` marks, every other one goes and the stride doubles: a
        file of any length keeps a timeline of a few hundred KB."""
        while max(len(self.seconds), len(self.filament)) > MAX_MARKS:
            self.seconds = self.seconds[::2]
            self.heating = self.heating[::2]
            self.filament = self.filament[::2]
            self.stride *= 2

    def _at(self, values: list[float], line: int, end: float, total: int) -> float:
        if not values:
            return 0.0
        line = max(0, min(line, total))
        slot, within = divmod(line, self.stride)
        if slot >= len(values):
            return end
        here = values[slot]
        after = values[slot + 1] if slot + 1 < len(values) else end
        span = min(self.stride, total - slot * self.stride) or 1
        return here + (after - here) * within / span


@dataclass(slots=True)
class Analysis:
    """Everything printhost knows about one file (keyed by its SHA-256)."""

    #: "fff" for a 3D printer's file, "cnc" for a GRBL machine's.
    kind: str = "fff"
    commands: int = 0
    #: The motion model's time (moves and dwells), and heating waits apart.
    motion_seconds: float = 0.0
    heating_seconds: float = 0.0
    dwell_seconds: float = 0.0
    #: Net filament pushed per extruder (mm), and its volume and weight.
    filament_mm: list[float] = field(default_factory=list)
    filament_volume_mm3: float = 0.0
    filament_weight_g: float = 0.0
    layers: list[Layer] = field(default_factory=list)
    #: Bounding box of extruding (fff) or cutting (cnc) moves: [min xyz, max xyz].
    bbox: list[list[float]] | None = None
    print_distance: float = 0.0
    travel_distance: float = 0.0
    slicer: dict[str, Any] = field(default_factory=dict)
    objects: list[str] = field(default_factory=list)
    #: CNC: tools used (T words) and the highest spindle speed (S with M3/M4).
    tools: list[int] = field(default_factory=list)
    spindle_max: float = 0.0
    #: Thumbnails found (stored apart): [{"width", "height", "format", "size"}].
    thumbnails: list[dict[str, Any]] = field(default_factory=list)
    timeline: Timeline = field(default_factory=Timeline)
    #: The preview's geometry (stored apart, toolpath.py): {"features": names,
    #: "bytes", "points", "layers": [[start, end) bytes per layer]}; {} if none.
    toolpath: dict[str, Any] = field(default_factory=dict)
    #: Why the analysis is partial or what it skipped, in words for people.
    notes: list[str] = field(default_factory=list)

    @property
    def total_seconds(self) -> float:
        return self.motion_seconds + self.heating_seconds

    @property
    def filament_total(self) -> float:
        return sum(self.filament_mm)

    def seconds_at(self, line: int) -> float:
        """Estimated seconds (motion and heating) before command *line* runs."""
        return self.timeline._at(
            self.timeline.seconds, line, self.total_seconds, self.commands
        )

    def heating_at(self, line: int) -> float:
        return self.timeline._at(
            self.timeline.heating, line, self.heating_seconds, self.commands
        )

    def filament_at(self, line: int) -> float:
        return self.timeline._at(
            self.timeline.filament, line, self.filament_total, self.commands
        )

    def layer_at(self, line: int) -> int:
        """0-based index of the layer command *line* belongs to (-1 before the first)."""
        starts = [layer.line for layer in self.layers]
        return bisect_right(starts, line) - 1

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["total_seconds"] = round(self.total_seconds, 1)
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Analysis:
        data = dict(data)
        data.pop("total_seconds", None)
        data["layers"] = [Layer(**layer) for layer in data.get("layers", [])]
        data["timeline"] = Timeline(**data.get("timeline", {}))
        return cls(**data)
