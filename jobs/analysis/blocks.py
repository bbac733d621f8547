"""The analyser's fast path: a block of lines at a time, moves as arrays.

`read_block(analyser, data)` scans the block (`scan.py`), reads its comments one
by one (they are few), and walks the commands in order. Commands that change how
moves are read or timed (modes, units, tools, limits, waits, arcs, homing: see
`_BREAKS`) are read one by one by the analyser's slow path; the plain moves and
`G92`s between two of them are a run, read at once: positions by forward fill and
cumulative sums, then filament, distances, bounding box, layers, and the planner.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

import numpy as np

from jobs.analysis.scan import E, F, Z, scan

if TYPE_CHECKING:
    from jobs.analysis.analyser import Analyser
    from jobs.analysis.scan import Lines

#: Bytes read per block (a few times this in numpy arrays while it is read).
BLOCK_BYTES = 1 << 20
_HEAD = re.compile(rb"\s*([GMTgmt])\s*([0-9]+)")
#: Commands that end a run: they change the state moves are read or timed with.
_BREAKS = {
    b"G": {0, 1, 2, 3, 4, 10, 11, 20, 21, 28, 90, 91, 92},  # G0, G1, G92 the scan refused
    b"M": {82, 83, 104, 109, 116, 140, 190, 201, 203, 204, 205, 207, 208, 220, 221,
           400, 566, 3, 4, 5},
    b"T": None,  # every tool change
}  # fmt: skip
_LAYER_STEP = 1e-4
#: Distinct comments remembered per file (`Analyser.known_comments`).
_KNOWN_COMMENTS = 4096
#: ...of at most this many bytes each (a file's comment can be megabytes long).
_KNOWN_LENGTH = 256
#: A remembered comment that starts no feature.
_INERT = -1


def read_block(an: Analyser, data: bytes) -> None:
    lines = scan(data)
    count = len(lines.starts)
    ends = np.empty(count, np.int64)
    ends[:-1] = lines.starts[1:] - 1
    ends[-1] = len(data) - 1
    commands = np.cumsum(lines.has_code) - lines.has_code + an._index
    offsets = lines.starts + an._offset
    markers = []
    feature_lines, feature_ids = [], []
    # Comments a file repeats (`;WIDTH:0.45`, `;TYPE:Perimeter`) are read once:
    # reading one again would change nothing, or start the same feature.
    known, thumbs = an.known_comments, an.thumbs
    commented = np.flatnonzero(lines.has_comment)
    for line, begin, end in zip(
        commented.tolist(),
        (lines.code_ends[commented] + 1).tolist(),
        ends[commented].tolist(),
        strict=True,
    ):
        raw = data[begin:end]
        reading_picture = thumbs.reading
        feature = None if reading_picture else known.get(raw)
        if feature is None:
            text = raw.decode("utf-8", "replace").rstrip("\r")
            if not text:
                continue
            feature = an.feature_of(text)
            if feature is None:
                if an.comment(text, int(offsets[line])):
                    markers.append(line)
                    continue
                if thumbs.reading or reading_picture:
                    continue
                feature = _INERT
            if len(known) < _KNOWN_COMMENTS and len(raw) <= _KNOWN_LENGTH:
                known[raw] = feature
        if feature != _INERT:
            feature_lines.append(line)
            feature_ids.append(feature)
    marker_lines = np.array(markers, np.int64)
    features = Features(an.feature, feature_lines, feature_ids)
    others = [
        (line, data[lines.starts[line] : lines.code_ends[line]].strip())
        for line in np.flatnonzero(lines.has_code & (lines.kind < 0)).tolist()
    ]
    runs_from = 0
    quiet = []
    for line, code in others:
        if not _breaks(code):
            quiet.append((line, code))
            continue
        _run(an, lines, commands, offsets, marker_lines, features, runs_from, line)
        an.feature = features.at(line)
        an.special(code, int(commands[line]), int(offsets[line]))
        runs_from = line + 1
    _run(an, lines, commands, offsets, marker_lines, features, runs_from, count)
    # Commands that do not end a run (fans, messages, M486...), in their order.
    for line, code in quiet:
        an.special(code, int(commands[line]), int(offsets[line]))
    an.feature = features.at(count)
    an._index = int(commands[-1] + lines.has_code[-1])
    an._offset += len(data)
    an.filament_marks_until(an._index)


class Features:
    """Which feature (`;TYPE:` comments) each line of a block is in."""

    def __init__(self, before: int, lines: list[int], ids: list[int]) -> None:
        self.before = before
        self.lines = np.array(lines, np.int64)
        self.ids = np.array(ids, np.int64)

    def at(self, line: int) -> int:
        where = int(np.searchsorted(self.lines, line, side="right")) - 1
        return int(self.ids[where]) if where >= 0 else self.before

    def of(self, rows: np.ndarray) -> np.ndarray:
        if not len(self.lines):
            return np.full(len(rows), self.before, np.int64)
        where = np.searchsorted(self.lines, rows, side="right") - 1
        return np.where(where >= 0, self.ids[np.maximum(where, 0)], self.before)


def _breaks(code: bytes) -> bool:
    head = _HEAD.match(code)
    if head is None:
        return False
    numbers = _BREAKS[head.group(1).upper()]
    return numbers is None or int(head.group(2)) in numbers


def _ffill(values: np.ndarray, first: float) -> np.ndarray:
    """Each NaN replaced by the last number before it (*first* before any)."""
    present = ~np.isnan(values)
    index = np.where(present, np.arange(len(values)), -1)
    np.maximum.accumulate(index, out=index)
    return np.where(index >= 0, values[np.maximum(index, 0)], first)


def _run(
    an: Analyser,
    lines: Lines,
    commands: np.ndarray,
    offsets: np.ndarray,
    markers: np.ndarray,
    features: Features,
    lo: int,
    hi: int,
) -> None:
    """Read the moves and G92s of lines [lo, hi) at once."""
    inside = markers[(markers >= lo) & (markers < hi)] if len(markers) else markers
    kinds = lines.kind[lo:hi]
    rows = np.flatnonzero(kinds >= 0) + lo
    if not len(rows):
        an._mark_pending |= bool(len(inside))
        return
    values = lines.values[rows]
    kind = lines.kind[rows]
    is_g92 = kind == 92
    moves = ~is_g92
    scale = 25.4 if an._inches else 1.0
    if is_g92.any():
        bare = is_g92 & np.isnan(values[:, :4]).all(axis=1)
        values[bare, :4] = 0.0  # `G92` alone: every axis is 0
    position = np.empty((len(rows), 4))
    for axis in range(4):
        column = values[:, axis] * scale
        absolute = an._absolute_e if axis == E else an._absolute
        start = an._pos[axis]
        if an.cnc and axis == E:
            position[:, axis] = start
        elif absolute:
            position[:, axis] = _ffill(column, start)
        else:
            steps = np.where(moves & ~np.isnan(column), column, 0.0)
            total = np.cumsum(steps)
            resets = np.where(is_g92 & ~np.isnan(column), column - total, np.nan)
            position[:, axis] = total + _ffill(resets, start)
    previous = np.empty_like(position)
    previous[0] = an._pos
    previous[1:] = position[:-1]
    feeds = values[:, F]
    given = ~np.isnan(feeds) & (feeds > 0)
    feeds = _ffill(np.where(given, feeds * scale / 60.0, np.nan), an._feed)
    an._pos = [float(v) for v in position[-1]]
    an._feed = float(feeds[-1])
    # The moves that move, from here on (a G92 or a move to where the head is
    # already are not moves), picked out once.
    delta = position - previous
    moving = moves & (
        (delta[:, 0] != 0.0)
        | (delta[:, 1] != 0.0)
        | (delta[:, 2] != 0.0)
        | (delta[:, 3] != 0.0)
    )
    if not moving.all():
        picked = np.flatnonzero(moving)
        if not len(picked):
            an._mark_pending |= bool(len(inside))
            return
        rows, delta, feeds, kind = (
            rows[picked],
            delta[picked],
            feeds[picked],
            kind[picked],
        )
        start_points, end_points = previous[picked], position[picked]
    else:
        start_points, end_points = previous, position
    rapid = kind == 0
    tags = commands[rows]
    an._moves += len(rows)
    xyz = np.sqrt(np.einsum("ij,ij->i", delta[:, :3], delta[:, :3]))
    if an.cnc:
        rapid = rapid.copy()
        if an._feed <= 0.0 and not rapid.all():
            missing = ~rapid & (feeds <= 0.0)
            if missing.any():
                rapid |= missing
                if "a cutting move has no feed rate" not in an.result.notes:
                    an.result.notes.append("a cutting move has no feed rate")
        cutting = ~rapid
    else:
        rapid = np.zeros(len(rows), bool)
        cutting = (delta[:, E] > 0.0) & (xyz > 0.0)
    # Filament, with the filament marks the run passes.
    pushed = np.zeros(len(rows))
    if not an.cnc:
        extruded = delta[:, E] * an._flow.get(an._tool, 1.0)
        before = an._filament_total
        np.cumsum(extruded[:-1], out=pushed[1:])
        pushed += before
        an.filament_marks_until(int(tags[-1]) + 1, tags, pushed)
        an.add_filament(float(extruded.sum()))
    else:
        an.filament_marks_until(int(tags[-1]) + 1)
    an.result.print_distance += float(xyz[cutting].sum())
    an.result.travel_distance += float(xyz[~cutting].sum())
    if cutting.any():
        # Column by column: numpy reduces a short axis slowly.
        low, high = [], []
        for axis in range(3):
            ends = end_points[:, axis][cutting]
            starts = start_points[:, axis][cutting]
            low.append(min(ends.min(), starts.min()))
            high.append(max(ends.max(), starts.max()))
        an.include_box(low, high)
    _layers(an, rows, tags, offsets, delta, end_points, cutting, inside)
    speed = np.where(rapid, 1e9, feeds * an._speed_factor)
    an.planner.add(tags, delta, speed)
    if an.toolpath is not None:
        an.draw(tags, start_points, end_points, cutting, speed, features.of(rows))


def _layers(
    an: Analyser,
    rows: np.ndarray,
    tags: np.ndarray,
    offsets: np.ndarray,
    delta: np.ndarray,
    end_points: np.ndarray,
    cutting: np.ndarray,
    markers: np.ndarray,
) -> None:
    """New layers among the run's moves: by the slicer's markers (*markers*: the
    marker lines of the run) and by height."""
    z_moves = np.flatnonzero(delta[:, Z] != 0.0)
    last_z = np.where(delta[:, Z] != 0.0, np.arange(len(rows)), -1)
    np.maximum.accumulate(last_z, out=last_z)

    def z_change_at(move: int) -> tuple[int, int]:
        at = int(last_z[move])
        if at < 0:
            return an._z_change
        return int(tags[at]), int(offsets[rows[at]])

    if an.cnc:
        if len(z_moves):
            an._z_change = z_change_at(len(rows) - 1)
        return
    printing = np.flatnonzero(cutting)
    # By the slicer's markers: the first extruding move after each marker.
    firsts = []
    if an._mark_pending and len(printing):
        firsts.append(int(printing[0]))
        an._mark_pending = False
    printing_rows = rows[printing]
    for marker in markers:
        after = np.searchsorted(printing_rows, marker)
        if after < len(printing):
            firsts.append(int(printing[after]))
        else:
            an._mark_pending = True
    for move in sorted(set(firsts)):
        z = float(end_points[move, Z])
        here = (int(tags[move]), int(offsets[rows[move]]))
        an.new_layer(an._marked_layers, z, z_change_at(move), here)
    # By height: an extruding move above every layer so far.
    if len(printing):
        heights = end_points[printing, Z]
        ceiling = np.maximum.accumulate(np.concatenate(([an._layer_z], heights)))
        rising = np.flatnonzero(heights > ceiling[:-1] + _LAYER_STEP)
        for at in rising:
            move = int(printing[at])
            z = float(heights[at])
            if z <= an._layer_z + _LAYER_STEP:
                continue
            an._layer_z = z
            here = (int(tags[move]), int(offsets[rows[move]]))
            an.new_layer(an._z_layers, z, z_change_at(move), here)
    if len(z_moves):
        an._z_change = z_change_at(len(rows) - 1)
