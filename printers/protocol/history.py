"""Compact history of every numbered line of a job, so any line can be sent again."""

from __future__ import annotations

from array import array

__all__ = ["LineHistory"]


class LineHistory:
    """The text of consecutive numbered lines `first`..`last`, kept since the last M110.

    All text lives in one bytearray; `_ends[i]` is where line `first + i` ends. A
    million-line job costs its own size plus 8 bytes a line, and no Python string is
    kept per line (Printrun keeps a dict of strings; OctoPrint only the last 50).
    """

    __slots__ = ("_data", "_ends", "_first")

    def __init__(self, first_n: int = 0) -> None:
        self._data = bytearray()
        self._ends = array("Q")
        self._first = first_n

    @property
    def first(self) -> int:
        """Number of the oldest line kept (the M110 line itself after a reset)."""
        return self._first

    @property
    def last(self) -> int:
        """Number of the newest line kept; `first - 1` while empty."""
        return self._first + len(self._ends) - 1

    def __len__(self) -> int:
        return len(self._ends)

    def __contains__(self, n: object) -> bool:
        return isinstance(n, int) and self._first <= n <= self.last

    def append(self, n: int, text: str) -> None:
        """Store line *n*; it must follow the last one (ValueError otherwise)."""
        if n != self.last + 1:
            raise ValueError(f"line {n} does not follow line {self.last}")
        self._data += text.encode("ascii")
        self._ends.append(len(self._data))

    def get(self, n: int) -> str:
        """The text of line *n* (KeyError when it is not kept)."""
        if n not in self:
            raise KeyError(n)
        index = n - self._first
        start = self._ends[index - 1] if index else 0
        return self._data[start : self._ends[index]].decode("ascii")

    def clear(self, first_n: int) -> None:
        """Forget every line; the next one appended must be *first_n*."""
        self._data = bytearray()
        self._ends = array("Q")
        self._first = first_n
