"""LineCursor: which lines a client gets, so a resume has no gap and no duplicate."""

from __future__ import annotations

from printers.live import LineCursor


def lines(*ids: int, kind: int = 4) -> list[dict]:
    return [{"id": i, "time": "", "text": f"line {i}", "type": kind} for i in ids]


def test_lines_the_client_already_has_are_dropped() -> None:
    cursor = LineCursor(last=5)
    sent = cursor.take(lines(4, 5, 6, 7))
    assert [line["id"] for line in sent] == [6, 7]
    assert cursor.last == 7
    assert cursor.take(lines(6, 7)) == []


def test_a_batch_after_missing_ids_reports_the_gap() -> None:
    cursor = LineCursor(last=10)
    assert cursor.gap(lines(14, 15)) == (11, 13)
    assert cursor.gap(lines(11, 12)) is None
    assert cursor.gap(lines(9, 10)) is None, "old lines are no gap"
    assert cursor.gap(lines(8, 9, 10, 11)) is None


def test_filling_the_gap_then_the_batch_gives_every_line_once() -> None:
    cursor = LineCursor(last=10)
    batch = lines(14, 15)
    first, last = cursor.gap(batch)
    sent = cursor.take(lines(*range(first, last + 1))) + cursor.take(batch)
    assert [line["id"] for line in sent] == [11, 12, 13, 14, 15]


def test_filter_bits_hide_kinds_but_the_cursor_moves_past_them() -> None:
    cursor = LineCursor(last=0, filter=1 | 2)
    batch = lines(1, kind=1) + lines(2, kind=2) + lines(3, kind=4)
    assert [line["id"] for line in cursor.take(batch)] == [3]
    assert cursor.last == 3
    assert cursor.gap(lines(4)) is None


def test_non_maskable_lines_are_never_filtered() -> None:
    cursor = LineCursor(last=0, filter=15)
    assert [line["id"] for line in cursor.take(lines(1, kind=8))] == [1]


def test_lines_pruned_before_the_client_read_them_give_a_notice() -> None:
    cursor = LineCursor(last=3)
    assert cursor.truncated(100) == {"type": "truncated", "first": 100}
    assert cursor.last == 99
    assert cursor.truncated(100) is None
    assert cursor.truncated(None) is None


def test_lines_out_of_order_in_a_batch_are_sent_in_id_order() -> None:
    cursor = LineCursor(last=0)
    assert [line["id"] for line in cursor.take(lines(3, 1, 2))] == [1, 2, 3]
