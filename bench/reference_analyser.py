"""A straightforward line-by-line G-code analyser: the yardstick for `make bench`.

It computes what printhost's analyser computes (planner time with junction
deviation and look-ahead, heating waits, filament, layers, bounding box, slicer
figures and thumbnails) the way one would write it first: read a line, cut the
comment, split the words into a dict, one object per move. It lives in bench/ only,
so the speed ratio is measured against real code rather than guessed.

    python -m bench.reference_analyser FILE   prints the figures and its own peak RSS
"""

from __future__ import annotations

import base64
import contextlib
import itertools
import json
import math
import resource
import sys
import time
from dataclasses import dataclass
from pathlib import Path


@dataclass
class Block:
    distance: float
    accel: float
    nominal_sq: float
    max_entry_sq: float
    entry_sq: float = 0.0


@dataclass
class Limits:
    max_feedrate: tuple = (300.0, 300.0, 5.0, 25.0)
    max_acceleration: tuple = (3000.0, 3000.0, 100.0, 10000.0)
    print_acceleration: float = 3000.0
    retract_acceleration: float = 3000.0
    travel_acceleration: float = 3000.0
    junction_deviation: float = 0.013


def block_time(block: Block, exit_sq: float) -> float:
    a = block.accel
    v0, v1 = math.sqrt(block.entry_sq), math.sqrt(exit_sq)
    vn = math.sqrt(max(block.nominal_sq, block.entry_sq, exit_sq))
    d_acc = (vn * vn - v0 * v0) / (2 * a)
    d_dec = (vn * vn - v1 * v1) / (2 * a)
    if d_acc + d_dec <= block.distance:
        return (vn - v0) / a + (vn - v1) / a + (block.distance - d_acc - d_dec) / vn
    d_acc = min(
        max((v1 * v1 - v0 * v0 + 2 * a * block.distance) / (4 * a), 0), block.distance
    )
    peak = math.sqrt(v0 * v0 + 2 * a * d_acc)
    return (peak - v0) / a + (peak - v1) / a


class Reference:
    def __init__(self) -> None:
        self.limits = Limits()
        self.blocks: list[Block] = []
        self.prev_unit: list[float] | None = None
        self.prev_nominal_sq = 0.0
        self.time = 0.0
        self.heating = 0.0
        self.position = [0.0, 0.0, 0.0, 0.0]
        self.absolute = True
        self.absolute_e = True
        self.feedrate = 25.0
        self.filament = 0.0
        self.layers: list[float] = []
        self.low = [math.inf] * 3
        self.high = [-math.inf] * 3
        self.notes: dict[str, str] = {}
        self.thumbnails: list[bytes] = []
        self.picture: list[str] | None = None
        self.temps = {"tool": 25.0, "bed": 25.0}

    def line(self, raw: str) -> None:
        if ";" in raw:
            code, comment = raw.split(";", 1)
            self.comment(comment.strip())
        else:
            code = raw
        code = code.strip()
        if not code:
            return
        parts = code.upper().split()
        words = {}
        for part in parts[1:]:
            with contextlib.suppress(ValueError):
                words[part[0]] = float(part[1:])
        command = parts[0]
        if command in ("G0", "G1"):
            self.move(words)
        elif command == "G90":
            self.absolute = self.absolute_e = True
        elif command == "G91":
            self.absolute = self.absolute_e = False
        elif command == "M82":
            self.absolute_e = True
        elif command == "M83":
            self.absolute_e = False
        elif command == "G92":
            for axis, letter in enumerate("XYZE"):
                if letter in words:
                    self.position[axis] = words[letter]
        elif command == "G4":
            self.flush()
            self.time += words.get("S", 0.0) + words.get("P", 0.0) / 1000
        elif command in ("M109", "M190") and "S" in words:
            self.flush()
            name = "bed" if command == "M190" else "tool"
            rate = 0.6 if name == "bed" else 2.0
            self.heating += max(0.0, words["S"] - self.temps[name]) / rate
            self.temps[name] = words["S"]

    def comment(self, text: str) -> None:
        if text.startswith("thumbnail begin"):
            self.picture = []
        elif text.startswith("thumbnail end") and self.picture is not None:
            self.thumbnails.append(base64.b64decode("".join(self.picture)))
            self.picture = None
        elif self.picture is not None:
            self.picture.append(text)
        elif "=" in text:
            key, value = text.split("=", 1)
            self.notes[key.strip()] = value.strip()

    def move(self, words: dict[str, float]) -> None:
        if "F" in words:
            self.feedrate = words["F"] / 60
        target = list(self.position)
        for axis, letter in enumerate("XYZE"):
            if letter in words:
                absolute = self.absolute_e if letter == "E" else self.absolute
                target[axis] = (
                    words[letter] if absolute else target[axis] + words[letter]
                )
        delta = [t - p for t, p in zip(target, self.position, strict=True)]
        self.position = target
        xyz = math.sqrt(delta[0] ** 2 + delta[1] ** 2 + delta[2] ** 2)
        distance = xyz if xyz > 1e-6 else abs(delta[3])
        if distance < 1e-9:
            return
        if delta[3] > 0 and xyz > 0:
            self.filament += delta[3]
            z = target[2]
            if not self.layers or z > self.layers[-1] + 1e-4:
                self.layers.append(z)
            for axis in range(3):
                self.low[axis] = min(self.low[axis], target[axis])
                self.high[axis] = max(self.high[axis], target[axis])
        elif delta[3]:
            self.filament += delta[3]
        limits = self.limits
        if delta[3] == 0:
            accel = limits.travel_acceleration
        elif xyz <= 1e-6:
            accel = limits.retract_acceleration
        else:
            accel = limits.print_acceleration
        feed = self.feedrate
        unit = [d / distance for d in delta]
        for axis in range(4):
            if unit[axis]:
                feed = min(feed, limits.max_feedrate[axis] / abs(unit[axis]))
                accel = min(accel, limits.max_acceleration[axis] / abs(unit[axis]))
        nominal_sq = feed * feed
        max_entry = 0.0
        if self.prev_unit is not None and self.prev_nominal_sq > 0:
            cos_theta = -sum(u * p for u, p in zip(unit, self.prev_unit, strict=True))
            if cos_theta > 0.999999:
                max_entry = 0.0025
            else:
                cos_theta = max(cos_theta, -0.999999)
                sin_half = math.sqrt(0.5 * (1 - cos_theta))
                max_entry = (
                    accel * limits.junction_deviation * sin_half / (1 - sin_half)
                )
                max_entry = min(max_entry, nominal_sq, self.prev_nominal_sq)
        self.prev_unit = unit
        self.prev_nominal_sq = nominal_sq
        self.blocks.append(Block(distance, accel, nominal_sq, max_entry))
        if len(self.blocks) >= 128:
            self.plan(keep=64)

    def plan(self, keep: int) -> None:
        blocks = self.blocks
        following = 0.0025
        for block in reversed(blocks):
            block.entry_sq = min(
                block.max_entry_sq, following + 2 * block.accel * block.distance
            )
            following = block.entry_sq
        for before, block in itertools.pairwise(blocks):
            block.entry_sq = min(
                block.entry_sq, before.entry_sq + 2 * before.accel * before.distance
            )
        done = len(blocks) - keep
        for index in range(done):
            exit_sq = blocks[index + 1].entry_sq if index + 1 < len(blocks) else 0.0025
            self.time += block_time(blocks[index], exit_sq)
        del blocks[:done]
        if blocks:
            blocks[0].max_entry_sq = blocks[0].entry_sq

    def flush(self) -> None:
        if self.blocks:
            self.plan(keep=0)
        self.prev_unit = None


def analyse(path: str) -> dict[str, object]:
    reference = Reference()
    with Path(path).open(encoding="utf-8", errors="replace") as handle:
        for raw in handle:
            reference.line(raw)
    reference.flush()
    return {
        "motion_seconds": round(reference.time, 1),
        "heating_seconds": round(reference.heating, 1),
        "filament_mm": round(reference.filament, 1),
        "layers": len(reference.layers),
        "thumbnails": len(reference.thumbnails),
    }


def main() -> int:
    started = time.perf_counter()
    figures = analyse(sys.argv[1])
    seconds = time.perf_counter() - started
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps({"seconds": seconds, "rss": rss, "figures": figures}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
