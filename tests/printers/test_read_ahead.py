"""The job file is read a batch at a time (spool.read_ahead): same lines, same order,
an error in the file only after every line before it."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from printers.worker.spool import read_ahead


def counted(items: list[int], pulled: list[int]) -> Iterator[int]:
    for item in items:
        pulled.append(item)
        yield item


def test_every_entry_comes_once_in_order_across_batches() -> None:
    assert list(read_ahead(iter(range(100)), 32)) == list(range(100))
    assert list(read_ahead(iter(range(64)), 32)) == list(range(64))
    assert list(read_ahead(iter([]), 32)) == []


def test_it_reads_no_more_than_one_batch_ahead() -> None:
    pulled: list[int] = []
    entries = read_ahead(counted(list(range(100)), pulled), 32)
    assert next(entries) == 0
    assert len(pulled) == 32
    for _ in range(31):
        next(entries)
    assert len(pulled) == 32
    assert next(entries) == 32
    assert len(pulled) == 64


def test_an_error_in_the_file_comes_after_the_lines_before_it() -> None:
    def broken() -> Iterator[int]:
        yield from range(40)
        raise ValueError("block 3 is damaged")

    entries = read_ahead(broken(), 32)
    got = [next(entries) for _ in range(40)]
    assert got == list(range(40))
    with pytest.raises(ValueError, match="block 3 is damaged"):
        next(entries)
