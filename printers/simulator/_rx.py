"""A UART receive ring in front of a firmware's line reader: full ring, lost bytes."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Callable

__all__ = ["LineReader"]

#: A partial line longer than this is cut (the firmware's own limit is far lower).
MAX_PARTIAL = 1024


class LineReader:
    """Bytes from the wire wait in a ring of *capacity* until the firmware reads them.

    The firmware reads whenever `can_read()` is true (Marlin: a command slot is
    free; GRBL: no line is blocked), line by line, calling `on_line(line, now)`
    with the line's bytes without its end. While it cannot read, arriving bytes
    fill the ring and the rest are dropped, as a UART's are. `\\r` ends a line
    too. Reading works on whole chunks (`bytes.find`), never byte by byte.
    """

    def __init__(
        self,
        capacity: int,
        on_line: Callable[[bytes, float], None],
        can_read: Callable[[], bool],
    ) -> None:
        self.capacity = capacity
        self._on_line = on_line
        self._can_read = can_read
        self._ring = bytearray()
        self._partial = bytearray()
        self._flushed = False
        self.dropped = 0
        self.received = 0
        #: While on_line runs: another whole line follows in the chunk being read.
        self._more = False

    @property
    def free(self) -> int:
        """Ring bytes free (GRBL reports it as the second `Bf:` number)."""
        return self.capacity - len(self._ring)

    @property
    def waiting(self) -> bool:
        """A whole line waits in the ring (Marlin reads serial before the SD card)."""
        return self._more or b"\n" in self._ring

    def feed(self, data: bytes, now: float) -> None:
        """Bytes that arrived at *now*."""
        self.received += len(data)
        if b"\r" in data:
            data = data.replace(b"\r", b"\n")
        if self._ring or not self._can_read():
            self._store(data)
            self.drain(now)
            return
        rest = self._read(data, now)
        if rest:
            self._store(rest)

    def drain(self, now: float) -> None:
        """Read what waits in the ring while the firmware can take it."""
        if not self._ring or not self._can_read():
            return
        ring = bytes(self._ring)
        self._ring.clear()
        rest = self._read(ring, now)
        if rest:
            self._ring[:0] = rest  # never overflows: these bytes were in the ring

    def flush(self) -> None:
        """Throw away the ring and the partial line (Marlin after a line error)."""
        self._ring.clear()
        self._partial.clear()
        self._flushed = True

    def _store(self, data: bytes) -> None:
        room = self.capacity - len(self._ring)
        if len(data) > room:
            self.dropped += len(data) - room
            data = data[:room]
        self._ring += data

    def _read(self, data: bytes, now: float) -> bytes:
        """Hand whole lines to the firmware; returns the bytes it could not take yet."""
        start = 0
        size = len(data)
        while start < size:
            end = data.find(b"\n", start)
            if end < 0:
                room = MAX_PARTIAL - len(self._partial)
                self._partial += data[start : start + max(room, 0)]
                return b""
            if self._partial:
                self._partial += data[start:end]
                line = bytes(self._partial)
                self._partial.clear()
            else:
                line = data[start:end]
            start = end + 1
            self._flushed = False
            self._more = data.find(b"\n", start) >= 0
            try:
                self._on_line(line, now)
            finally:
                self._more = False
            if self._flushed:
                return b""  # the rest had arrived too, so the flush took it
            if not self._can_read():
                return data[start:]
        return b""
