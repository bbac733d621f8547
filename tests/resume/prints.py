"""Generated files for the resume tests: a layered 3D print and a CNC pocket."""

from __future__ import annotations

import math


def layered_print(layers: int = 8, per_layer: int = 120) -> str:
    """A print with what a resume must put back: heaters, absolute E, a fan that
    comes on at layer 2, a setting, retractions with Z hops, PrusaSlicer's layer
    marks."""
    lines = [
        "; generated: a layered print", "M140 S60", "M104 S210", "M190 S60",
        "M109 S210", "G21", "G90", "M82", "G28", "G92 E0", "M204 P800 T1500",
    ]  # fmt: skip
    e = 0.0
    for layer in range(layers):
        z = round(0.2 * (layer + 1), 2)
        lines += [";LAYER_CHANGE", f";Z:{z}", f"G1 Z{z} F600"]
        if layer == 2:
            lines.append("M106 S200")
        for i in range(per_layer):
            angle = 2 * math.pi * i / per_layer + layer * 0.1
            x, y = 100 + 20 * math.cos(angle), 100 + 20 * math.sin(angle)
            e += 0.05
            lines.append(f"G1 X{x:.3f} Y{y:.3f} E{e:.5f} F1800")
        e -= 0.8
        lines += [f"G1 E{e:.5f} F2400", f"G1 Z{z + 0.4:.2f} F600"]
        lines += ["G1 X100 Y80 F6000", f"G1 Z{z} F600"]
        e += 0.8
        lines.append(f"G1 E{e:.5f} F2400")
    lines += ["M107", "M104 S0", "M140 S0"]
    return "\n".join(lines) + "\n"


def cnc_pocket(passes: int = 6, per_pass: int = 150) -> str:
    """A pocket cut in passes in G55 with its offset set by the file, spindle and
    coolant on, retracts between passes (a CNC job's modal state)."""
    lines = [
        "; generated: a pocket", "G10 L2 P2 X5 Y5 Z-2", "G21 G90 G94", "G55",
        "M3 S12000", "M8", "G0 Z5", "G0 X10 Y10",
    ]  # fmt: skip
    lines += _passes(passes, per_pass, centre=30, radius=20, retract="G0 Z5")
    lines += ["M9", "M5", "G0 Z10"]
    return "\n".join(lines) + "\n"


def cnc_zeroed_here(passes: int = 6, per_pass: int = 150) -> str:
    """A pocket whose file sets its own zero where the tool stands (G92, as
    "zero here" jobs do) and retracts in machine coordinates (G53) between
    passes."""
    lines = [
        "; generated: a pocket zeroed with G92", "G21 G90 G94", "G54", "G0 Z20",
        "G0 X15 Y12", "G92 X0 Y0 Z0", "M3 S12000", "G0 Z5", "G0 X10 Y10",
    ]  # fmt: skip
    lines += _passes(passes, per_pass, centre=20, radius=10, retract="G53 G0 Z30")
    lines += ["M5", "G53 G0 Z30"]
    return "\n".join(lines) + "\n"


def _passes(
    passes: int, per_pass: int, *, centre: float, radius: float, retract: str
) -> list[str]:
    """Down half a millimetre a pass, once around the circle, then *retract*."""
    lines = []
    for depth in range(passes):
        z = -0.5 * (depth + 1)
        lines += [f"G1 Z{z} F300", "G1 F1200"]
        for i in range(per_pass):
            angle = 2 * math.pi * i / per_pass
            x = centre + radius * math.cos(angle)
            y = centre + radius * math.sin(angle)
            lines.append(f"X{x:.3f} Y{y:.3f}")
        lines += [retract, "G0 X10 Y10"]
    return lines
