"""A small model of what a Marlin firmware does with commands, for the object tests.

It follows G90/G91, M82/M83, G92 and G0-G3 (ends only) and lists every move that
extrudes as a segment; the tests compare the segments of what was sent with those
of the file.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from printers.streaming import Line
from printers.streaming.objects import ObjectMark, object_mark

_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")


@dataclass(frozen=True)
class Segment:
    """An extruding move: from, to (x, y) and the E it pushed, with its object."""

    start: tuple[float, float]
    end: tuple[float, float]
    e: float
    z: float
    object: str | None = None


@dataclass
class Machine:
    absolute: bool = True
    absolute_e: bool = True
    pos: dict[str, float] = field(
        default_factory=lambda: {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}
    )
    segments: list[Segment] = field(default_factory=list)
    #: E moved by moves that do not extrude (retracts, unretracts, wipes).
    other_e: float = 0.0
    active: str | None = None
    #: M486 as Marlin's CANCEL_OBJECTS runs it: the running number, the cancelled.
    m486: int = -1
    m486_cancelled: set[int] = field(default_factory=set)

    def run(self, command: str) -> None:
        text = command.strip()
        head = text.split(" ", 1)[0].upper()
        words = {k.upper(): float(v) for k, v in _WORD.findall(text[len(head) :])}
        if head == "G90":
            self.absolute = self.absolute_e = True
        elif head == "G91":
            self.absolute = self.absolute_e = False
        elif head == "M82":
            self.absolute_e = True
        elif head == "M83":
            self.absolute_e = False
        elif head == "G92":
            for axis, value in (words or dict.fromkeys("XYZE", 0.0)).items():
                if axis in self.pos:
                    self.pos[axis] = value
        elif head == "M486":
            if "S" in words:
                self.m486 = int(words["S"])
            if "P" in words:
                self.m486_cancelled.add(int(words["P"]))
        elif head in ("G0", "G1", "G2", "G3"):
            if self.m486 in self.m486_cancelled:  # the firmware keeps X, Y, Z
                words = {k: v for k, v in words.items() if k in "EF"}
            self._move(words)

    def _move(self, words: dict[str, float]) -> None:
        before = dict(self.pos)
        for axis in "XYZE":
            if axis in words:
                relative = not (self.absolute_e if axis == "E" else self.absolute)
                self.pos[axis] = before[axis] + words[axis] if relative else words[axis]
        pushed = self.pos["E"] - before["E"]
        moved = self.pos["X"] != before["X"] or self.pos["Y"] != before["Y"]
        if pushed > 1e-9 and moved:
            self.segments.append(
                Segment(
                    (round(before["X"], 4), round(before["Y"], 4)),
                    (round(self.pos["X"], 4), round(self.pos["Y"], 4)),
                    round(pushed, 5),
                    round(self.pos["Z"], 4),
                    self.active,
                )
            )
        else:
            self.other_e += pushed


def entries_of(text: str) -> list[Line | ObjectMark]:
    """A file's text as the stream reads it: commands (comments out) and marks."""
    out: list[Line | ObjectMark] = []
    index = offset = 0
    for raw in text.splitlines(keepends=True):
        offset += len(raw.encode())
        command = raw.split(";", 1)[0].strip()
        if command:
            out.append(Line(index, command, offset))
            index += 1
        elif (mark := object_mark(raw.encode())) is not None:
            out.append(mark)
    return out


def file_segments(entries: list[Line | ObjectMark]) -> Machine:
    """The file run whole, each segment with the object it belongs to."""
    machine = Machine()
    for entry in entries:
        if isinstance(entry, ObjectMark):
            machine.active = entry.name
        else:
            machine.run(entry.text)
    return machine


def m486_labels(text: str) -> str:
    """The slice as PrusaSlicer 2.6 labels for firmware: `M486 S<n>` and names."""
    names = re.findall(r"^; printing object (\S+) id:(\d+) copy 0$", text, re.M)
    names = dict((int(n), name) for name, n in names)
    define = ["M486 T3"] + [f"M486 S{n}\nM486 A{name}" for n, name in names.items()]
    text = text.replace("M82 ;", "\n".join([*define, "M486 S-1", "M82 ;"]), 1)
    text = re.sub(
        r"^; printing object \S+ id:(\d+) copy 0$", r"M486 S\1", text, flags=re.M
    )
    return re.sub(r"^; stop printing object .*$", "M486 S-1", text, flags=re.M)
