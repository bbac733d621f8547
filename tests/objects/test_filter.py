"""The object filter (printers/streaming/objects.py): rules O1-O9, without Django."""

from __future__ import annotations

import functools
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from printers.streaming import Line
from printers.streaming.objects import ObjectFilter, ObjectMark, object_mark
from tests.objects.gcode_model import Machine, entries_of, file_segments

THREE = Path(__file__).parents[1] / "data" / "prusaslicer-2.5_three-boxes.gcode"


def run(entries, *, cancel_at: int | None = None, name: str = "B", cancelled=()):
    """Sent lines; *cancel_at*: cancel *name* once that many lines were read."""
    objects = ObjectFilter(entries, cancelled=cancelled)
    sent = []
    for line in objects:
        sent.append(line)
        if cancel_at is not None and len(sent) == cancel_at:
            objects.cancel(name)
    return objects, sent


def texts(lines: list[Line]) -> list[str]:
    return [line.text for line in lines]


TWO = """\
G90
M82
G92 E0
; printing object A id:0 copy 0
G1 X0 Y0 F3000
G1 X10 Y0 E1 F1200
; stop printing object A id:0 copy 0
; printing object B id:1 copy 0
G1 E0.2 F2400
G1 Z0.6 F7800
G1 X50 Y50
G1 Z0.2
G1 E1 F2400
G1 X60 Y50 E2 F1200
G1 X60 Y60 E3
G1 X61 Y61 E2.9
; stop printing object B id:1 copy 0
; printing object A id:0 copy 0
G1 E0.9 F2400
G1 Z0.6 F7800
G1 X0 Y10
G1 Z0.2
G1 E2.9 F2400
G1 X10 Y10 E4 F1200
; stop printing object A id:0 copy 0
"""


def test_object_mark_reads_prusaslicer_labels_as_the_analysis_names_them():
    assert object_mark(b"; printing object box-a.stl id:0 copy 0\n") == ObjectMark(
        "box-a.stl"
    )
    assert object_mark(b"; stop printing object box-a.stl id:0 copy 0\n") == (
        ObjectMark(None)
    )
    assert object_mark(b";TYPE:Perimeter\n") is None
    assert object_mark(b"; objects_info = {}\n") is None


def test_without_a_cancel_every_line_is_sent_unchanged():
    entries = entries_of(TWO)
    _, sent = run(entries)
    assert sent == [e for e in entries if isinstance(e, Line)]


def test_a_cancelled_object_loses_its_extrusion_and_keeps_travel_and_hops():
    objects, sent = run(entries_of(TWO), cancelled=["B"])
    assert texts(sent) == [
        "G90", "M82", "G92 E0",
        "G1 X0 Y0 F3000", "G1 X10 Y0 E1 F1200",
        # B: its retract, lift, travel, lower and unretract stay; its extrusion goes,
        # its wipe (E drawn back while moving) stays.
        "G1 E0.2 F2400", "G1 Z0.6 F7800", "G1 X50 Y50", "G1 Z0.2", "G1 E1 F2400",
        # O5, O6: the file's E and feedrate before the wipe.
        "G92 E3", "G1 F1200", "G1 X61 Y61 E2.9",
        # The wipe left the head where the file has it (no O7 move); then A.
        "G1 E0.9 F2400", "G1 Z0.6 F7800", "G1 X0 Y10", "G1 Z0.2", "G1 E2.9 F2400",
        "G1 X10 Y10 E4 F1200",
    ]  # fmt: skip
    assert objects.objects == ["A", "B"]


def test_absolute_e_gets_g92_before_the_next_e_after_skipped_extrusion():
    text = TWO.replace("G1 X61 Y61 E2.9\n", "")
    _, sent = run(entries_of(text), cancelled=["B"])
    at = texts(sent).index("G1 E0.9 F2400")
    # The file pushed B's E to 3; the firmware is at 1: it learns the file's E.
    assert texts(sent)[at - 2 : at + 1] == ["G0 X60 Y60", "G92 E3", "G1 E0.9 F2400"]


def test_relative_e_needs_no_g92():
    text = """\
G90
M83
; printing object B id:1 copy 0
G1 X50 Y50 F7800
G1 X60 Y50 E1 F1200
G1 X60 Y60 E1
; stop printing object B id:1 copy 0
G1 E-0.8 F2400
G1 X0 Y0 F7800
"""
    _, sent = run(entries_of(text), cancelled=["B"])
    assert texts(sent) == [
        "G90", "M83", "G1 X50 Y50 F7800", "G0 X60 Y60", "G1 E-0.8 F2400",
        "G1 X0 Y0 F7800",
    ]  # fmt: skip


def test_a_dropped_move_keeps_its_z_and_its_feedrate():
    text = """\
G90
M82
; printing object B id:1 copy 0
G1 X50 Y50 F7800
G1 X60 Y50 Z0.4 E1 F1200
; stop printing object B id:1 copy 0
G1 X0 Y0
"""
    _, sent = run(entries_of(text), cancelled=["B"])
    assert texts(sent) == [
        "G90", "M82", "G1 X50 Y50 F7800", "G1 Z0.4", "G0 X60 Y50", "G1 F1200",
        "G1 X0 Y0",
    ]  # fmt: skip


def test_relative_xyz_sends_the_move_without_its_e():
    text = "G91\n; printing object B\nG1 X10 Y0 E1 F1200\n; stop printing object B\n"
    _, sent = run(entries_of(text), cancelled=["B"])
    assert texts(sent) == ["G91", "G1 X10 Y0 F1200"]


def test_a_cancel_takes_effect_at_the_next_line_read():
    entries = entries_of(TWO)
    cancel_after = 11  # B's first extrusion was read (and sent): it stays
    _, sent = run(entries, cancel_at=cancel_after)
    assert texts(sent)[cancel_after - 1] == "G1 X60 Y50 E2 F1200"
    # The next one goes; the wipe draws E back from where the file has it.
    assert texts(sent)[cancel_after : cancel_after + 3] == [
        "G92 E3", "G1 X61 Y61 E2.9", "G1 E0.9 F2400",
    ]  # fmt: skip


def test_added_lines_carry_the_index_of_the_line_before():
    entries = entries_of(TWO)
    _, sent = run(entries, cancelled=["B"])
    g92 = next(line for line in sent if line.text == "G92 E3")
    dropped = next(e for e in entries if getattr(e, "text", "") == "G1 X60 Y60 E3")
    assert (g92.index, g92.end_offset) == (dropped.index, dropped.end_offset)
    indexes = [line.index for line in sent]
    assert indexes == sorted(indexes), "indexes never go back"


def test_klipper_and_m486_labels_name_objects():
    text = """\
EXCLUDE_OBJECT_DEFINE NAME=part_1
EXCLUDE_OBJECT_START NAME=part_1
G1 X1 Y1 E1
EXCLUDE_OBJECT_END NAME=part_1
M486 S0
M486 Apart two
G1 X2 Y2 E2
M486 S-1
M486 S0
G1 X3 Y3 E3
M486 S-1
"""
    objects, sent = run(entries_of(text), cancelled=["part two"])
    assert objects.objects == ["part_1", "part two"]
    assert objects.m486_ids == {"part two": 0}
    assert "G1 X1 Y1 E1" in texts(sent)
    assert "G1 X2 Y2 E2" not in texts(sent)
    assert "G1 X3 Y3 E3" not in texts(sent), "M486 S0 again is the same object"


def test_the_three_box_slice_without_one_box_extrudes_exactly_the_other_two():
    entries = entries_of(THREE.read_text())
    whole = file_segments(entries)
    assert {s.object for s in whole.segments} == {
        "box-a.stl", "box-b.stl", "box-c.stl",
    }  # fmt: skip
    objects, sent = run(entries, cancelled=["box-b.stl"])
    printed = Machine()
    for line in sent:
        printed.run(line.text)
    kept = [
        (s.start, s.end, s.e, s.z) for s in whole.segments if s.object != "box-b.stl"
    ]
    assert [(s.start, s.end, s.e, s.z) for s in printed.segments] == kept
    # Retracts and unretracts balance as in the file, and E ends where it does.
    assert round(printed.other_e, 4) == round(whole.other_e, 4)
    assert round(printed.pos["E"], 4) == round(whole.pos["E"], 4)
    assert printed.pos["Z"] == whole.pos["Z"]


def test_an_unretract_in_place_after_dropped_moves_travels_there_first():
    """Found by the test below: B's second move extrudes where its first ended;
    with the first dropped, sending it as is drew a line from where the head was."""
    text = "G90\nM82\n; printing object B id:0 copy 0\nG1 X1 Y0 E1.0\n"
    text += "G1 X1 Y0 E2.0\n; stop printing object B id:0 copy 0\n"
    objects, sent = run(entries_of(text), cancel_at=1)
    printed = Machine()
    for line in sent:
        printed.run(line.text)
    assert texts(sent) == ["G90", "M82", "G0 X1 Y0", "G92 E1", "G1 X1 Y0 E2.0"]
    assert printed.segments == [] or all(s.start == s.end for s in printed.segments)


def _with_only_b_left_out(sent: list, segments: list) -> bool:
    """*sent* (end, e) keys are *segments* in order with some of B's left out. Any
    way of matching counts: B's segment and the next part's may look the same."""

    @functools.cache
    def fits(i: int, j: int) -> bool:
        if i == len(sent):
            return all(s.object == "B" for s in segments[j:])
        if j == len(segments):
            return False
        here = segments[j]
        taken = (here.end, here.e) == sent[i] and fits(i + 1, j + 1)
        return taken or (here.object == "B" and fits(i, j + 1))

    return fits(0, 0)


mode = st.sampled_from(["M82", "M83", "G92 E0", "G92 E5.5"])
move = st.tuples(
    st.integers(0, 50), st.integers(0, 50), st.floats(-1, 2).map(lambda e: round(e, 3))
)
part = st.tuples(st.sampled_from(["A", "B", None]), st.lists(st.one_of(mode, move)))


def _program(parts: list) -> str:
    lines, e_abs, e = ["G90", "M82"], True, 0.0
    for name, body in parts:
        if name:
            lines.append(f"; printing object {name} id:0 copy 0")
        for item in body:
            if isinstance(item, str):
                lines.append(item)
                if item == "M82":
                    e_abs = True
                elif item == "M83":
                    e_abs = False
                else:
                    e = float(item.split("E")[1])
                continue
            x, y, step = item
            e += step
            lines.append(f"G1 X{x} Y{y} E{round(e, 5) if e_abs else step}")
        if name:
            lines.append(f"; stop printing object {name} id:0 copy 0")
    return "\n".join(lines) + "\n"


@settings(max_examples=300, deadline=None)
@given(st.lists(part, max_size=8), st.integers(0, 60))
def test_e_stays_the_files_for_any_mix_of_absolute_and_relative_e(parts, cancel_at):
    """Cancel B after any line: the segments sent are the file's, minus some of B's;
    every other E move is sent; after each file line that names E in absolute E,
    the firmware's E is the file's."""
    entries = entries_of(_program(parts))
    whole = file_segments(entries)
    objects, sent = run(entries, cancel_at=cancel_at or None)
    file_e = {}
    model = Machine()
    for entry in entries:
        if isinstance(entry, Line):
            model.run(entry.text)
            file_e[id(entry)] = model.pos["E"]
    printed = Machine()
    for line in sent:
        printed.run(line.text)
        if id(line) in file_e and " E" in line.text and printed.absolute_e:
            assert round(printed.pos["E"], 4) == round(file_e[id(line)], 4), line
    # What was sent is the file's segments in order, with only some of B's left out.
    sent_keys = [(s.end, s.e) for s in printed.segments]
    assert _with_only_b_left_out(sent_keys, whole.segments), (
        "only B's extrusion may be left out"
    )
    assert round(printed.other_e, 4) == round(whole.other_e, 4)


_ARGUMENT_TEXT = st.text(alphabet="XYZEFIJRxe+-.0123456789 ßé*;", max_size=24)


@settings(max_examples=500, deadline=None)
@given(_ARGUMENT_TEXT)
def test_the_quick_reading_of_words_agrees_with_the_pattern_on_any_text(args):
    # Plain `X1.5 Y2` is read without the regex; any other text must come out
    # exactly as the regex reads it (a sign twice, `X 5`, `X1Y2`, an ß, `1e3`).
    from printers.streaming.objects import _WORD, _words

    expected = {letter.upper(): float(value) for letter, value in _WORD.findall(args)}
    assert _words(args) == expected


@settings(max_examples=50, deadline=None)
@given(st.integers(1, 400), st.sampled_from([1, 7, 64]))
def test_moves_followed_in_batches_send_what_moves_followed_one_by_one_send(
    cancel_at, batch
):
    """Plain moves are followed a batch at a time (FOLLOW_BATCH): a cancel after
    any of them sends the same lines as following each move at once."""
    import printers.streaming.objects as module

    moves = [f"G1 X{i % 37} Y{i % 23} E{i * 0.05:.2f}" for i in range(300)]
    text = "\n".join(["G90", "M82", "; printing object B", *moves,
                      "; stop printing object B", "G1 X1 Y1 F900"]) + "\n"  # fmt: skip
    eager_batch, module.FOLLOW_BATCH = module.FOLLOW_BATCH, 1
    try:
        _, eager = run(entries_of(text), cancel_at=cancel_at)
    finally:
        module.FOLLOW_BATCH = eager_batch
    module.FOLLOW_BATCH = batch
    try:
        _, batched = run(entries_of(text), cancel_at=cancel_at)
    finally:
        module.FOLLOW_BATCH = eager_batch
    assert texts(batched) == texts(eager)
