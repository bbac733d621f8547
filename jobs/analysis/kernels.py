"""The analyser's compiled loops (numba): the few places a file is read a byte or a
move at a time.

G-code is read a byte at a time by nature, and a compiled loop does it at 120 to
180 MB/s where whole-array tricks in numpy managed 14 to 44 (each number took
a dozen passes over temporary arrays); the same holds for thinning the preview's
polylines (each point looks at its kept neighbours) and for a corner's speed
(a dozen transcendental steps per move). Each function here is the inner loop of
one step, and its module says what the step means:

- `scan_lines`: `scan.py` (lines, commands, G0/G1/G92 and their numbers);
- `polylines` and `thin`: `toolpath.py` (the preview's polylines and their
  records);
- `block_limits` and `deviation_junctions`: `planner.py` (each move's length,
  speed and acceleration within the machine's limits; the speed at each corner).

numba compiles each loop on its first call and keeps the machine code in its cache
(`cache=True`, beside this file or in numba's cache folder), so later processes
load it in under a second. numba and LLVM take about 120 MB of memory, so
this module is imported by the first analysis, never by the web server or a
printer's worker (they import the analyser's modules, not these loops).
"""

from __future__ import annotations

import numba
import numpy as np

from jobs.analysis.planner import MIN_SPEED_SQ
from jobs.analysis.toolpath import PASSES, TOLERANCE

# Bytes by value, as numba reads them.
_LF, _SPACE, _TAB, _SEMI, _OPEN, _CLOSE, _STAR = 10, 32, 9, 59, 40, 41, 42
_POINT, _MINUS, _PLUS, _ZERO, _NINE = 46, 45, 43, 48, 57


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _blank(byte: int) -> bool:  # pragma: no cover - compiled
    """Space, tab and the line-end bytes (as `bytes.strip` takes them)."""
    return byte == _SPACE or (9 <= byte <= 13)


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _digit_or_point(byte: int) -> bool:  # pragma: no cover - compiled
    return (_ZERO <= byte <= _NINE) or byte == _POINT


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _column(byte: int) -> int:  # pragma: no cover - compiled
    """The `values` column of a word's letter (either case), -1 for others."""
    upper = byte & 0xDF
    if upper == 88:  # X
        return 0
    if upper == 89:  # Y
        return 1
    if upper == 90:  # Z
        return 2
    if upper == 69:  # E
        return 3
    if upper == 70:  # F
        return 4
    return -1


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _code_after_comments(a: np.ndarray, at: int, stop: int) -> bool:  # pragma: no cover
    """Whether a[at:stop], which starts with `(`, holds anything but `(...)`
    comments and blanks (an unclosed comment runs to *stop*)."""
    inside = False
    for i in range(at, stop):
        byte = a[i]
        if inside:
            inside = byte != _CLOSE
        elif byte == _OPEN:
            inside = True
        elif not _blank(byte):
            return True
    return False


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _number(a: np.ndarray, begin: int, stop: int) -> float:  # pragma: no cover
    """The number written at a[begin:stop] (digits, a point, signs)."""
    mantissa = 0.0
    decimals = 0
    seen_point = False
    for i in range(begin, stop):
        byte = a[i]
        if byte == _POINT and not seen_point:
            seen_point = True
            continue
        mantissa = mantissa * 10.0 + (byte - _ZERO if _ZERO <= byte <= _NINE else 0)
        if seen_point:
            decimals += 1
    # One division by an exact power of ten: correctly rounded for any number of
    # up to 15 digits, which every G-code number is.
    value = mantissa / 10.0**decimals if decimals else mantissa
    return -value if a[begin] == _MINUS else value


@numba.njit(cache=True, nogil=True, boundscheck=False)
def scan_lines(
    a: np.ndarray,
    starts: np.ndarray,
    code_ends: np.ndarray,
    has_code: np.ndarray,
    kind: np.ndarray,
    values: np.ndarray,
) -> None:  # pragma: no cover - compiled; tested through `scan`
    size = len(a)
    last = size - 1
    line = 0
    start = 0
    while start < size:
        # The line's end, its first `;` and whether it holds `(` or `*` before it.
        end = start
        code_end = -1
        odd = False
        while a[end] != _LF:
            byte = a[end]
            if code_end < 0:
                if byte == _SEMI:
                    code_end = end
                elif byte in (_OPEN, _STAR):
                    odd = True
            end += 1
        if code_end < 0:
            code_end = end
        first = start
        while first < end and _blank(a[first]):
            first += 1
        code = first < code_end
        if code and a[first] == _OPEN:
            code = _code_after_comments(a, first, code_end)
        starts[line] = start
        code_ends[line] = code_end
        has_code[line] = code
        for column in range(5):
            values[line, column] = np.nan
        # G0 / G1 / G92, read only when nothing odd is in the command. The bytes
        # after the code may be the next line's: they are only compared.
        what = -1
        if code and not odd and (a[first] | 0x20) == 103:  # g
            one = a[min(first + 1, last)]
            two = a[min(first + 2, last)]
            if (one == _ZERO or one == _ZERO + 1) and not _digit_or_point(two):
                what = one - _ZERO
            elif (
                one == _NINE  # `G92`
                and two == 50
                and not _digit_or_point(a[min(first + 3, last)])
            ):
                what = 92
        kind[line] = what
        if what >= 0:
            # Words: a letter right after a blank or a number, then its number.
            i = first + 1
            while i < code_end:
                column = _column(a[i])
                before = a[i - 1]
                if column >= 0 and (
                    before in (_SPACE, _TAB) or _digit_or_point(before)
                ):
                    begin = i + 1
                    stop = begin
                    while stop < size and (
                        _digit_or_point(a[stop])
                        or a[stop] == _MINUS
                        or a[stop] == _PLUS
                    ):
                        stop += 1
                    if stop > begin:
                        values[line, column] = _number(a, begin, stop)
                    i = stop if stop > begin else i + 1
                else:
                    i += 1
        line += 1
        start = end + 1


@numba.njit(cache=True, nogil=True)
def polylines(
    tags: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    drawn: np.ndarray,
    speeds: np.ndarray,
    features: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, int]:  # pragma: no cover - compiled
    """Moves cut into thinned polylines, as `toolpath.py`'s records: the words, the
    word at which each record starts, and the points kept."""
    count = len(tags)
    key = np.empty(count, np.int64)
    lines = 0
    for i in range(count):
        speed = min(max(np.rint(speeds[i]), 0.0), 65535.0)
        key[i] = np.int64(drawn[i]) | (features[i] << 8) | (np.int64(speed) << 16)
        if i == 0 or key[i] != key[i - 1]:
            lines += 1
    # Points: each polyline's start, then its moves' ends.
    points = np.empty((count + lines, 2))
    groups = np.empty(count + lines, np.int64)
    begins = np.empty(lines, np.int64)
    line = -1
    at = 0
    for i in range(count):
        if i == 0 or key[i] != key[i - 1]:
            line += 1
            begins[line] = i
            points[at, 0], points[at, 1] = starts[i, 0], starts[i, 1]
            groups[at] = line
            at += 1
        points[at, 0], points[at, 1] = ends[i, 0], ends[i, 1]
        groups[at] = line
        at += 1
    keep = thin(points, groups)
    kept = 0
    for i in range(len(keep)):
        kept += keep[i]
    # Words: 3 of header per polyline, 2 per point.
    out = np.empty(3 * lines + 2 * kept, np.uint32)
    flat = out.view(np.float32)
    header = np.empty(lines, np.int64)
    word = 0
    point = 0
    for line in range(lines):
        begin = begins[line]
        header[line] = word
        out[word] = tags[begin]
        out[word + 1] = key[begin]
        word += 3
        size = 0
        while point < len(groups) and groups[point] == line:
            if keep[point]:
                flat[word] = points[point, 0]
                flat[word + 1] = points[point, 1]
                word += 2
                size += 1
            point += 1
        out[header[line] + 2] = size
    return out, header, kept


@numba.njit(cache=True, nogil=True)
def thin(points: np.ndarray, groups: np.ndarray) -> np.ndarray:  # pragma: no cover
    """Which points to keep: ends of every polyline, and any point further than
    `TOLERANCE` from the line through its kept neighbours.

    Each pass looks at every other point still kept (alternating between passes),
    with the neighbours it had when the pass began: two neighbours never go in one
    pass, so the kept points bound the error."""
    count = len(points)
    keep = np.ones(count, np.bool_)
    if count < 3:
        return keep
    kept = np.arange(count)
    size = count
    for parity in range(PASSES):
        if size < 3:
            break
        for at in range(1 + parity % 2, size - 1, 2):
            previous, middle, following = kept[at - 1], kept[at], kept[at + 1]
            if (
                groups[middle] != groups[previous]
                or groups[middle] != groups[following]
            ):
                continue  # a polyline's first or last point
            bx, by = points[previous, 0], points[previous, 1]
            cx, cy = points[following, 0] - bx, points[following, 1] - by
            mx, my = points[middle, 0] - bx, points[middle, 1] - by
            length = np.hypot(cx, cy)
            if length <= 0.0:
                continue
            # Near the chord, and between its ends (a turn back is never thinned).
            if abs(cx * my - cy * mx) > TOLERANCE * max(length, 1e-9):
                continue
            along = mx * cx + my * cy
            onward = (points[following, 0] - points[middle, 0]) * cx + (
                points[following, 1] - points[middle, 1]
            ) * cy
            if along >= 0.0 and onward >= 0.0:
                keep[middle] = False
        size = 0
        for at in range(count):
            if keep[at]:
                kept[size] = at
                size += 1
    return keep


@numba.njit(cache=True, nogil=True)
def deviation_junctions(
    unit: np.ndarray,
    prev: np.ndarray,
    accel: np.ndarray,
    nominal_sq: np.ndarray,
    prev_nominal: np.ndarray,
    distance: np.ndarray,
    max_accel: np.ndarray,
    deviation: float,
    first_free: bool,  # noqa: FBT001 - numba takes no keyword-only arguments
) -> np.ndarray:  # pragma: no cover - compiled; tested through Planner
    """Each block's highest entry speed² by junction deviation, from its unit
    vector and the one before (as Marlin's planner: the corner's own acceleration
    within every axis' limit; short segments of a curve by the curve's radius)."""
    count = len(accel)
    out = np.empty(count)
    for i in range(count):
        cos_theta = 0.0
        for axis in range(4):
            cos_theta -= prev[i, axis] * unit[i, axis]
        if cos_theta > 0.999999:
            out[i] = MIN_SPEED_SQ  # a reversal
            continue
        cos_theta = max(cos_theta, -0.999999)
        length = 0.0
        for axis in range(4):
            step = unit[i, axis] - prev[i, axis]
            length += step * step
        length = np.sqrt(length)
        junction_accel = accel[i]
        if length > 0.0:
            for axis in range(4):
                share = abs(unit[i, axis] - prev[i, axis]) / length
                if max_accel[axis] > 0.0 and share > 0.0:
                    junction_accel = min(junction_accel, max_accel[axis] / share)
        sin_half = np.sqrt(0.5 * (1.0 - cos_theta))
        vmax_sq = junction_accel * deviation * sin_half / (1.0 - sin_half)
        # Short segments of a curve: limit by the curve's own radius (Marlin's
        # JD_HANDLE_SMALL_SEGMENTS), or arcs would be taken far too fast.
        theta = np.arccos(-cos_theta)
        if distance[i] < 1.0 and theta > 0.0:
            vmax_sq = min(vmax_sq, distance[i] * junction_accel / theta)
        out[i] = min(vmax_sq, min(nominal_sq[i], prev_nominal[i]))
    if first_free and count:
        out[0] = 0.0  # from rest
    return out


@numba.njit(cache=True, nogil=True)
def block_limits(
    deltas: np.ndarray,
    feedrates: np.ndarray,
    accelerations: np.ndarray,
    floors: np.ndarray,
    max_feed: np.ndarray,
    max_accel: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Each move's length, acceleration and speed, as the firmware plans a block:
    the length in space (or the filament's, for a move of E alone); travel, print
    or retract acceleration (*accelerations*, in that order); the feedrate raised
    to the firmware's floor (*floors*: extruding, travel); then both slowed so no
    axis outruns its limit (0: none). A length under 1e-9 mm is no block."""
    count = len(feedrates)
    distance = np.empty(count)
    accel = np.empty(count)
    feed = np.empty(count)
    for i in range(count):
        xyz = np.sqrt(
            deltas[i, 0] * deltas[i, 0]
            + deltas[i, 1] * deltas[i, 1]
            + deltas[i, 2] * deltas[i, 2]
        )
        spatial = xyz > 1e-6
        length = xyz if spatial else abs(deltas[i, 3])
        extruding = deltas[i, 3] != 0.0
        if not extruding:
            a = accelerations[0]
        elif spatial:
            a = accelerations[1]
        else:
            a = accelerations[2]
        f = max(max(feedrates[i], floors[0] if extruding else floors[1]), 1e-3)
        if length >= 1e-9:
            for axis in range(4):
                share = abs(deltas[i, axis]) / length
                if share > 0.0:
                    if max_feed[axis] > 0.0:
                        f = min(f, max_feed[axis] / share)
                    if max_accel[axis] > 0.0:
                        a = min(a, max_accel[axis] / share)
        distance[i] = length
        accel[i] = max(a, 1e-3)
        feed[i] = f
    return distance, accel, feed
