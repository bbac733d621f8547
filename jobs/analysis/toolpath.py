"""The toolpath of a file, layer by layer, for the browser's preview.

The analyser hands every run of moves here as arrays; they are cut into polylines
(a new one where the move's kind, feature or speed changes), thinned (a point that
lies within `TOLERANCE` of the segment between its neighbours goes; never two
neighbours in one pass, so no drawn line strays more than PASSES x TOLERANCE from
the file's), and written to *sink* as they come: nothing grows with the file but
the file itself.

One record per polyline, little-endian, 4-byte words (a browser reads it as one
Uint32Array and one Float32Array over the same bytes):

    word 0      first command of the polyline (uint32)
    word 1      kind (bits 0-7: 0 travel, 1 extrusion or cut), feature (bits 8-15:
                index in the features list), speed in mm/s (bits 16-31)
    word 2      number of points, n
    words 3..   n points: x, y (float32, mm)

`finish(layers)` says where each layer's records start and end in the sink.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, BinaryIO

import numpy as np

if TYPE_CHECKING:
    from jobs.analysis.result import Layer

#: Millimetres a thinned point may lie off the drawn line.
TOLERANCE = 0.02
#: Passes of thinning (each may drop every other point of a straight stretch).
PASSES = 3
#: Features beyond this many share the last index (a file naming hundreds of
#: features is not a slicer's).
MAX_FEATURES = 255
#: The most bytes of toolpath one file gets (a large real print: tens of MB). Past
#: it the preview shows what was written: a small compressed file that unpacks to
#: gigabytes of moves must not fill the disk, nor one layer a viewer's request.
MAX_BYTES = 256 << 20


class ToolpathWriter:
    """Writes polylines to *sink* as runs of moves come in."""

    def __init__(self, sink: BinaryIO) -> None:
        self.sink = sink
        self.features: list[str] = [""]
        self._feature_ids: dict[str, int] = {"": 0}
        self.written = 0
        self.points = 0
        #: MAX_BYTES were written: the rest of the file is not drawn.
        self.full = False
        # The last runs' first commands and byte offsets of their records, so a
        # layer that starts a little before the run that found it is still placed.
        self._recent: list[tuple[np.ndarray, np.ndarray]] = []

    def feature(self, name: str) -> int:
        """The index of feature *name* (a slicer's `;TYPE:` comment)."""
        name = name.strip()[:40]
        known = self._feature_ids.get(name)
        if known is None:
            if len(self.features) > MAX_FEATURES:
                return MAX_FEATURES  # not remembered: names without end, one index
            known = len(self.features)
            self.features.append(name)
            self._feature_ids[name] = known
        return known

    def add(
        self,
        tags: np.ndarray,
        starts: np.ndarray,
        ends: np.ndarray,
        drawn: np.ndarray,
        speeds: np.ndarray,
        features: np.ndarray,
    ) -> None:
        """Moves from *starts* to *ends* (x, y columns), each with its command, whether
        it extrudes or cuts, its speed (mm/s) and feature index."""
        count = len(tags)
        if not count or self.full:
            return
        if self.written >= MAX_BYTES:
            self.full = True
            return
        from jobs.analysis import kernels  # numba: loaded by the first analysis only

        out, header, points = kernels.polylines(
            np.ascontiguousarray(tags, np.int64),
            np.ascontiguousarray(starts[:, :2], np.float64),
            np.ascontiguousarray(ends[:, :2], np.float64),
            np.ascontiguousarray(drawn, np.bool_),
            np.ascontiguousarray(speeds, np.float64),
            np.ascontiguousarray(features, np.int64),
        )
        offsets = self.written + 4 * header
        self.sink.write(out.tobytes())
        self.written += 4 * len(out)
        self.points += points
        self._recent = [*self._recent[-1:], (out[header].astype(np.int64), offsets)]

    def offset_of(self, command: int) -> int:
        """Byte offset of the first record at or after *command*, among the records
        of the last runs (else the end of what is written)."""
        for tags, offsets in self._recent:
            at = int(np.searchsorted(tags, command))
            if at < len(tags):
                return int(offsets[at])
        return self.written

    def finish(self, starts: list[int], layers: list[Layer]) -> list[list[int]]:
        """Each layer's [start, end) bytes, from *starts* (the byte offset found for
        each layer as it began, by `offset_of`)."""
        bounds = []
        for number in range(len(layers)):
            start = starts[number] if number < len(starts) else self.written
            end = starts[number + 1] if number + 1 < len(starts) else self.written
            bounds.append([start, max(start, end)])
        return bounds
