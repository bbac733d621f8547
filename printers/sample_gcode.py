"""Generated G-code for tests, benchmarks and the demo: short segments and long lines."""

from __future__ import annotations

import math
import random


def segments(count: int, *, seed: int = 1, cnc: bool = False) -> str:
    """*count* short G1 moves along a wobbly circle, like a slicer's curved perimeter.

    *cnc* leaves out extrusion (GRBL has no E axis) and sets a feed rate first.
    """
    rng = random.Random(seed)
    lines = ["; generated: short segments", "G21", "G90"]
    lines += ["G94", "G1 F3000"] if cnc else ["M83"]
    for i in range(count):
        angle = i * 0.01
        x = 100 + 50 * math.cos(angle) + rng.uniform(-0.05, 0.05)
        y = 100 + 50 * math.sin(angle) + rng.uniform(-0.05, 0.05)
        extrude = "" if cnc else f" E{rng.uniform(0.01, 0.05):.5f}"
        lines.append(f"G1 X{x:.3f} Y{y:.3f}{extrude}")
    return "\n".join(lines) + "\n"


def long_lines(count: int, *, seed: int = 2) -> str:
    """*count* long moves (about 60 characters each), each with a trailing comment."""
    rng = random.Random(seed)
    lines = ["; generated: long lines", "G21", "G90"]
    for _ in range(count):
        x, y, z = (rng.uniform(0, 200) for _ in range(3))
        feed = rng.uniform(600, 6000)
        lines.append(f"G1 X{x:.6f} Y{y:.6f} Z{z / 20:.6f} F{feed:.4f} ; long move")
    return "\n".join(lines) + "\n"


def commands_of(text: str) -> list[str]:
    """The commands a firmware should execute for *text* (comments and blanks out)."""
    from printers.protocol.checksum import clean_line

    return [c for c in (clean_line(raw) for raw in text.splitlines()) if c]
