"""The compiled byte scan (`jobs.analysis.scan`): what it calls a move, and its
numbers, against a plain reading of the same lines."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jobs.analysis.analyser import Analyser
from jobs.analysis.scan import scan

NAN = math.nan


def one(line: bytes) -> tuple[int, bool, list[float]]:
    lines = scan(line + b"\n")
    assert len(lines.starts) == 1
    return int(lines.kind[0]), bool(lines.has_code[0]), lines.values[0].tolist()


def same(found: list[float], expected: list[float]) -> bool:
    return all(
        (math.isnan(a) and math.isnan(b)) or a == b
        for a, b in zip(found, expected, strict=True)
    )


@pytest.mark.parametrize(
    ("line", "kind", "values"),
    [
        (b"G1 X1 Y2.5 E-0.8 F1800", 1, [1, 2.5, NAN, -0.8, 1800]),
        (b"G0X10Y20", 0, [10, 20, NAN, NAN, NAN]),
        (b"  g1 x.5 z+3", 1, [0.5, NAN, 3, NAN, NAN]),
        (b"G1 X1 ; to the right", 1, [1, NAN, NAN, NAN, NAN]),
        (b"G1 X1 X2", 1, [2, NAN, NAN, NAN, NAN]),  # the last word wins
        (b"G92 E0", 92, [NAN, NAN, NAN, 0, NAN]),
        (b"G92", 92, [NAN] * 5),
        (b"G1 MOVE E1", 1, [NAN, NAN, NAN, 1, NAN]),  # the E of MOVE is no word
        (b"G1 X 1", 1, [NAN] * 5),  # no number right after the letter
    ],
)
def test_moves_and_their_numbers(line: bytes, kind: int, values: list[float]) -> None:
    found_kind, has_code, found = one(line)
    assert (found_kind, has_code) == (kind, True)
    assert same(found, values), found


@pytest.mark.parametrize(
    "line",
    [
        b"G10",  # firmware retraction, not G1
        b"G92.1",
        b"G0.5 X1",
        b"G1 X1 (then) Y2",  # parentheses: the slow path reads it
        b"N10 G1 X1*33",  # line number and checksum
        b"M104 S200",
        b"T1",
    ],
)
def test_lines_the_fast_path_leaves_to_the_slow_one(line: bytes) -> None:
    kind, has_code, values = one(line)
    assert (kind, has_code) == (-1, True)
    assert all(math.isnan(v) for v in values)


@pytest.mark.parametrize(
    ("line", "has_code"),
    [
        (b"", False),
        (b"   \t\r", False),
        (b"; a comment", False),
        (b"(a comment)", False),
        (b"(unclosed comment", False),
        (b"(a comment) G28", True),
        (b"  G28 ; home", True),
    ],
)
def test_what_holds_a_command(line: bytes, has_code: bool) -> None:
    assert one(line)[1] is has_code


def test_line_starts_and_comment_ends_across_a_block() -> None:
    data = b"G1 X1\n; only a comment\n\nG1 Y2 ; and one here\r\n"
    lines = scan(data)
    assert lines.starts.tolist() == [0, 6, 23, 24]
    assert [bool(v) for v in lines.has_comment] == [False, True, False, True]
    assert data[lines.code_ends[3] :].startswith(b"; and one here")


_numbers = st.decimals(
    min_value=-10000, max_value=10000, places=5, allow_nan=False, allow_infinity=False
)


@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.tuples(st.sampled_from("XYZEFxyzef"), _numbers, st.sampled_from(["", " "])),
        max_size=6,
    ),
    st.sampled_from([b"G1", b"G0", b"g1"]),
)
def test_numbers_equal_a_plain_reading(words: list, head: bytes) -> None:
    """Any move line: each word's number is what Python's float() reads from it,
    to the last bit (the last word of a letter wins)."""
    line = (
        head
        + b" "
        + b"".join(f"{letter}{value:f}{gap}".encode() for letter, value, gap in words)
    )
    kind, has_code, values = one(line)
    expected = [NAN] * 5
    for letter, value, _gap in words:
        expected["XYZEF".index(letter.upper())] = float(f"{value:f}")
    assert kind == (0 if head == b"G0" else 1)
    assert same(values, expected), (line, values, expected)


def test_a_thumbnail_is_read_whole_even_when_its_lines_were_seen_before() -> None:
    """Comments a file repeats are read once, but never inside a thumbnail: a
    picture's lines can equal earlier comments, and each one is part of it."""
    png = (
        "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNk"
        "+M9QDwADhgGAWjR9awAAAABJRU5ErkJggg=="
    )
    half = len(png) // 2
    text = (
        f"; {png[:half]}\n; {png[half:]}\nG1 X1 E1\n"
        f"; thumbnail begin 1x1 {len(png)}\n; {png[:half]}\n; {png[half:]}\n"
        "; thumbnail end\nG1 X2 E2\n"
    )
    analyser = Analyser()
    analyser.feed(text.encode())
    analyser.finish()
    assert [(p.width, p.height) for p in analyser.pictures] == [(1, 1)]
    assert analyser.pictures[0].data.startswith(b"\x89PNG")


def test_the_scan_reads_a_whole_file_as_the_lines_say() -> None:
    """Every G1 of a generated block is found, with its numbers."""
    rows = [(i * 0.125, -i * 0.5, i % 7 * 0.05) for i in range(5000)]
    data = b"".join(f"G1 X{x} Y{y} E{e:.5f}\n".encode() for x, y, e in rows)
    lines = scan(data)
    assert (lines.kind == 1).all()
    expected = np.array(
        [[x, y, math.nan, float(f"{e:.5f}"), math.nan] for x, y, e in rows]
    )
    assert np.array_equal(lines.values, expected, equal_nan=True)
