"""Where a file's objects are: their ranges for the preview, and the filter's place
at a resume line (sans-IO; both read the file's entries through an ObjectFilter
with nothing cancelled, so every line comes out as the file has it)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from printers.streaming.objects import ObjectFilter

if TYPE_CHECKING:
    from collections.abc import Iterable

    from printers.streaming.objects import ObjectMark
    from printers.streaming.streams import Line

__all__ = ["object_ranges", "place_at"]


def object_ranges(
    entries: Iterable[Line | ObjectMark], *, limit: int = 100_000
) -> dict[str, list[list[int]]]:
    """Each object's commands as [first, end) index ranges (for the preview), at
    most *limit* ranges in all."""
    ranges: dict[str, list[list[int]]] = {}
    objects = ObjectFilter(entries)
    count = 0
    for line in objects:
        name = objects.active
        if name is None or line.index < 0:
            continue
        spans = ranges.setdefault(name, [])
        if spans and spans[-1][1] >= line.index:
            spans[-1][1] = line.index + 1
        elif count < limit:
            spans.append([line.index, line.index + 1])
            count += 1
    return ranges


def place_at(entries: Iterable[Line | ObjectMark], line: int) -> dict[str, Any]:
    """`ObjectFilter.place()` once the file's commands before *line* were read:
    what a run resumed at *line* starts its filter with (rule O10).

    The marks after command *line* - 1 are not read: the resumed run reads them,
    from that command's end on.
    """
    objects = ObjectFilter(entries)
    if line > 0:
        for sent in objects:
            if sent.index >= line - 1:
                break
    return objects.place()
