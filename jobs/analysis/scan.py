"""A block of G-code lines read at once with numpy: the analyser's fast path.

`scan(data)` takes whole lines (the block ends with a line end) and finds, for every
line at once: where it starts, where its command ends (at `;`), whether it holds a
command at all, whether that command is a plain move (`G0`/`G1`) or a `G92`, and
the X, Y, Z, E and F numbers of those lines. Numbers are parsed digit by digit
with array arithmetic (exact to the last bit or two of a double, far finer than any
machine moves). Everything else (other commands, comments) is left to the caller
line by line: those lines are few.

Lines a plain reading could get wrong are never called moves: a command with
`(...)` comments, a line number `N...`, or a word this reader does not parse.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

_PARENTHESES = re.compile(rb"\([^)]*\)?")
#: Columns of `Lines.values`.
X, Y, Z, E, F = range(5)
_COLUMN = np.full(256, -1, np.int8)
for _letter, _column in zip("XYZEF", (X, Y, Z, E, F), strict=True):
    _COLUMN[ord(_letter)] = _column
_POW10 = 10.0 ** np.arange(-30, 31)
_BLANK = np.zeros(256, bool)
_BLANK[[32, 9, 13, 10, 12, 11]] = True
#: Each byte's value as a digit (0 for a sign or a point).
_DIGIT_VALUE = np.zeros(256)
_DIGIT_VALUE[48:58] = np.arange(10)


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
    ends = np.flatnonzero(a == 10)
    count = len(ends)
    starts = np.empty(count, np.int64)
    starts[0] = 0
    starts[1:] = ends[:-1] + 1
    # Where each line's command ends: its first `;`, else its line end.
    code_ends = ends.copy()
    semis = np.flatnonzero(a == 59)
    if len(semis):
        holder = np.searchsorted(ends, semis)
        first = np.ones(len(semis), bool)
        first[1:] = holder[1:] != holder[:-1]
        code_ends[holder[first]] = semis[first]
    has_comment = code_ends < ends
    # The first byte of each line that is not blank.
    first_solid = starts.copy()
    lead = a[starts]
    indented = np.flatnonzero(_BLANK[lead] & (starts < ends))
    if len(indented):
        # Few lines start blank (empty lines are not among them: their first
        # byte is their end): find their first other byte one by one.
        for line in indented:
            at, stop = int(starts[line]), int(ends[line])
            while at < stop and _BLANK[a[at]]:
                at += 1
            first_solid[line] = at
    has_code = first_solid < code_ends
    for line in np.flatnonzero(
        has_code & (a[np.minimum(first_solid, len(a) - 1)] == 40)
    ):
        # A line that starts with a (...) comment holds a command only after it.
        code = data[int(first_solid[line]) : int(code_ends[line])]
        has_code[line] = bool(_PARENTHESES.sub(b"", code).strip())
    kind = _kinds(a, first_solid, has_code, code_ends, ends)
    values = np.full((count, 5), np.nan)
    wanted = np.flatnonzero(kind >= 0)
    if len(wanted):
        _words(a, ends, code_ends, first_solid, kind, values)
    return Lines(starts, code_ends, has_code, has_comment, kind, values)


def _kinds(
    a: np.ndarray,
    first: np.ndarray,
    has_code: np.ndarray,
    code_ends: np.ndarray,
    ends: np.ndarray,
) -> np.ndarray:
    """G0 / G1 / G92 lines the fast path may read; -1 for the rest."""
    size = len(a)
    at = np.minimum(first, size - 1)
    letter = a[at] | 0x20  # lower case
    one = a[np.minimum(at + 1, size - 1)]
    two = a[np.minimum(at + 2, size - 1)]
    three = a[np.minimum(at + 3, size - 1)]
    is_g = has_code & (letter == ord("g"))
    # `G0`/`G1` followed by a non-digit, non-point; `G92` followed by the same.
    move = is_g & ((one == 48) | (one == 49)) & _word_ends(two)
    g92 = is_g & (one == 57) & (two == 50) & _word_ends(three)
    kind = np.full(len(first), -1, np.int16)
    kind[move] = one[move] - 48
    kind[g92] = 92
    # Parentheses or checksums in the command: the slow path reads those lines.
    odd = np.flatnonzero((a == 40) | (a == 42))
    if len(odd):
        holder = np.searchsorted(ends, odd)
        inside = odd < code_ends[holder]
        kind[holder[inside]] = -1
    return kind


def _word_ends(byte: np.ndarray) -> np.ndarray:
    """The code's number ends here (not a digit or a point: `G1 `, `G1X`, not `G10`)."""
    return ~(((byte >= 48) & (byte <= 57)) | (byte == 46))


def _words(
    a: np.ndarray,
    ends: np.ndarray,
    code_ends: np.ndarray,
    first: np.ndarray,
    kind: np.ndarray,
    values: np.ndarray,
) -> None:
    """Fill *values* with the X Y Z E F numbers of the lines whose kind is >= 0."""
    upper = a & 0xDF
    letters = np.flatnonzero(
        (upper == 88) | (upper == 89) | (upper == 90) | (upper == 69) | (upper == 70)
    )
    if not len(letters):
        return
    holder = np.searchsorted(ends, letters)
    keep = (
        (kind[holder] >= 0) & (letters < code_ends[holder]) & (letters > first[holder])
    )
    # A letter inside a word (the E of `MOVE`) is not a word: it must follow a
    # blank or a number.
    before = a[letters - 1]
    keep &= (
        (before == 32)
        | (before == 9)
        | ((before >= 48) & (before <= 57))
        | (before == 46)
    )
    letters, holder = letters[keep], holder[keep]
    if not len(letters):
        return
    numeric = ((a >= 48) & (a <= 57)) | (a == 46) | (a == 45) | (a == 43)
    stops = np.flatnonzero(~numeric)
    begin = letters + 1
    end = stops[np.searchsorted(stops, begin)]
    length = end - begin
    keep = length > 0
    letters, holder, begin, length = (
        letters[keep],
        holder[keep],
        begin[keep],
        length[keep],
    )
    if not len(letters):
        return
    values[holder, _COLUMN[upper[letters]]] = _numbers(a, begin, length)


def _numbers(a: np.ndarray, begin: np.ndarray, length: np.ndarray) -> np.ndarray:
    """The numbers written at a[begin : begin + length] (sign, digits, one point)."""
    count = len(begin)
    total = int(length.sum())
    token_start = np.cumsum(length) - length
    # Each byte's position: consecutive within a number, jumping between numbers.
    step = np.ones(total, np.int64)
    step[0] = begin[0]
    step[token_start[1:]] = begin[1:] - (begin[:-1] + length[:-1]) + 1
    position = np.cumsum(step)
    chars = a[position]
    token = np.repeat(np.arange(count), length)
    # Each number's point (its end when it has none); a second point is ignored.
    point = begin + length
    dots = np.flatnonzero(chars == 46)
    point[token[dots[::-1]]] = position[dots[::-1]]
    at_point = point[token]
    exponent = at_point - position
    exponent -= exponent > 0
    np.clip(exponent, -30, 30, out=exponent)
    exponent += 30
    magnitude = np.add.reduceat(_DIGIT_VALUE[chars] * _POW10[exponent], token_start)
    return np.where(a[begin] == 45, -magnitude, magnitude)
