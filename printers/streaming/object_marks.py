"""The marker comments that say which object a file's lines print (rule O2 in
objects.py): read from the lines that send nothing, as the analysis reads them."""

from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = ["MAX_NAME", "ObjectMark", "object_mark", "object_name"]

#: Longest object name kept (the analysis cuts at the same length).
MAX_NAME = 200

_PRINTING = re.compile(
    r"^\s*;\s*printing object\s+(.+?)\s*(?:id:\d+\s+copy\s+\d+)?\s*$", re.I
)
_STOP = re.compile(r"^\s*;\s*stop printing object\b", re.I)


@dataclass(frozen=True, slots=True)
class ObjectMark:
    """A marker comment: *name* starts printing, or None: the object stops."""

    name: str | None


def object_mark(raw: bytes) -> ObjectMark | None:
    """The marker a raw file line holds (rule O2), or None for any other line.

    Cheap for the lines that are not markers: the reader calls it only for lines
    that send nothing (comments, blank lines).
    """
    if b"object" not in raw:
        return None
    text = raw.decode("utf-8", "replace")
    if _STOP.match(text):
        return ObjectMark(None)
    found = _PRINTING.match(text)
    if found is None:
        return None
    return ObjectMark(object_name(found.group(1)))


def object_name(text: str) -> str:
    """A name as the file gives it, trimmed and cut as the analysis cuts it."""
    return text.strip().strip("\"'").strip()[:MAX_NAME]
