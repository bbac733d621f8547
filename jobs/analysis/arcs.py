"""G2/G3 arcs in the XY plane, cut into chords as the firmware cuts them.

Marlin cuts arcs into chords of at most `arc_segment` mm; GRBL cuts them so no
chord strays more than `arc_tolerance` ($12) from the arc. The arc's outermost
points (where it crosses the X or Y axis through its centre) are given apart for
the bounding box, which chords alone would cut short.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: Chords of one arc at most (a huge arc at a tiny tolerance must not hang).
MAX_PIECES = 10_000


@dataclass(frozen=True, slots=True)
class Arc:
    #: End points of the chords (X Y Z E), the last being the target itself.
    points: list[list[float]]
    #: Outermost XY points the arc passes (for the bounding box).
    extremes: list[tuple[float, float]]


def cut_arc(
    start: list[float],
    target: list[float],
    center: tuple[float, float] | None,
    *,
    clockwise: bool,
    segment: float,
    tolerance: float,
) -> Arc:
    """The chords from *start* to *target* around *center* (None: a straight line)."""
    if center is None:
        return Arc([list(target)], [])
    start_angle = math.atan2(start[1] - center[1], start[0] - center[0])
    end_angle = math.atan2(target[1] - center[1], target[0] - center[0])
    radius = math.hypot(start[0] - center[0], start[1] - center[1])
    sweep = end_angle - start_angle
    if clockwise:
        if sweep >= -1e-9:
            sweep -= 2 * math.pi
    elif sweep <= 1e-9:
        sweep += 2 * math.pi
    length = abs(sweep) * radius
    if radius <= 0.0 or length <= 0.0:
        return Arc([list(target)], [])
    if tolerance > 0.0 and radius > tolerance:
        chord = 2.0 * math.sqrt(tolerance * (2.0 * radius - tolerance))
        pieces = max(1, math.floor(length / chord))
    else:
        pieces = max(1, math.floor(length / max(segment, 0.01)))
    pieces = min(pieces, MAX_PIECES)
    points = []
    for piece in range(1, pieces):
        share = piece / pieces
        angle = start_angle + sweep * share
        points.append(
            [
                center[0] + radius * math.cos(angle),
                center[1] + radius * math.sin(angle),
                start[2] + (target[2] - start[2]) * share,
                start[3] + (target[3] - start[3]) * share,
            ]
        )
    points.append(list(target))
    extremes = []
    for quarter in range(4):
        angle = quarter * math.pi / 2
        turned = (angle - start_angle) % (2 * math.pi)
        if sweep < 0:
            turned = (start_angle - angle) % (2 * math.pi)
        if turned <= abs(sweep):
            extremes.append(
                (
                    center[0] + radius * math.cos(angle),
                    center[1] + radius * math.sin(angle),
                )
            )
    return Arc(points, extremes)


def center_from_radius(
    start: list[float], end: list[float], radius: float, *, clockwise: bool
) -> tuple[float, float] | None:
    """The centre of the arc of *radius* (negative: the longer way) from start to end."""
    dx, dy = end[0] - start[0], end[1] - start[1]
    chord = math.hypot(dx, dy)
    if chord == 0.0 or abs(radius) < chord / 2:
        return None
    height = math.sqrt(max(radius * radius - chord * chord / 4, 0.0))
    # The centre lies left of the chord for G3 with R>0 (and right for G2).
    sign = -1.0 if clockwise else 1.0
    if radius < 0:
        sign = -sign
    mid = (start[0] + dx / 2, start[1] + dy / 2)
    return (mid[0] - sign * height * dy / chord, mid[1] + sign * height * dx / chord)
