"""A block of G-code lines read in one compiled pass: the analyser's fast path.

`scan(data)` takes whole lines (the block ends with a line end) and finds, for every
line: where it starts, where its command ends (at `;`), whether it holds a command
at all, whether that command is a plain move (`G0`/`G1`) or a `G92`, and the X, Y,
Z, E and F numbers of those lines. Everything else (other commands, comments) is
left to the caller line by line: those lines are few.

The pass is one loop over the bytes, compiled (`kernels.scan_lines`).

Lines a plain reading could get wrong are never called moves: a command with
`(...)` comments or a checksum `*`, a line number `N...`, or a word this reader
does not parse. A number is what follows its letter directly (`X-1.5`): digits, a
point and signs; a second point, or a sign after the first byte, counts as a zero
digit (such a number is garbage to any reader; this one stays finite).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Columns of `Lines.values`.
X, Y, Z, E, F = range(5)


@dataclass(frozen=True, slots=True)
class Lines:
    """What `scan` found in a block of lines (all arrays have one entry per line)."""

    starts: np.ndarray
    code_ends: np.ndarray
    has_code: np.ndarray
    has_comment: np.ndarray
    #: 0 for G0, 1 for G1, 92 for G92, -1 for any other line.
    kind: np.ndarray
    #: X, Y, Z, E, F of move and G92 lines; NaN where the word is absent.
    values: np.ndarray


def scan(data: bytes) -> Lines:
    """Read *data*, whole lines ending with b"\\n"."""
    a = np.frombuffer(data, np.uint8)
    count = int(np.count_nonzero(a == 10))
    starts = np.empty(count, np.int64)
    code_ends = np.empty(count, np.int64)
    has_code = np.empty(count, np.bool_)
    kind = np.empty(count, np.int16)
    values = np.empty((count, 5))
    from jobs.analysis import kernels  # numba: loaded by the first analysis only

    kernels.scan_lines(a, starts, code_ends, has_code, kind, values)
    ends = np.empty(count, np.int64)
    ends[:-1] = starts[1:] - 1
    ends[-1:] = len(a) - 1
    return Lines(starts, code_ends, has_code, code_ends < ends, kind, values)
