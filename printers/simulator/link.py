"""The wire between host and firmware, sans-IO: latency plus a UART's baud/10 bytes per second."""

from __future__ import annotations

import re
from collections import deque

__all__ = ["Wire"]

#: Slack, in bytes, when turning a time into a byte count. Monotonic clocks run
#: to 1e6 s and more, where a float's rounding is worth about 1e-4 of a byte at
#: 1 Mbaud; a hundredth of a byte early is invisible to any reader.
SLACK_BYTES = 0.01


class Wire:
    """One direction of a serial line, first in first out.

    A byte put in at time t leaves the sender once the bytes before it have, takes
    10/baud seconds on the line (8N1) and arrives *latency* seconds later. `None`
    baud means an unthrottled line (latency still applies). Segments are stored
    whole, so a 4 kB write costs one entry, not 4,000 timers.

    *wake* names the bytes the reader acts on (for example b"\\n"). With it,
    `next_arrival()` is when the next such byte arrives (or, if none is pending, the
    last pending byte), so a reader that only cares about whole lines is woken once
    a line, not once a byte. Without it, `next_arrival()` is the next byte's arrival.
    """

    def __init__(
        self, baud: int | None, latency: float = 0.0, *, wake: bytes | None = None
    ) -> None:
        if baud is not None and baud <= 0:
            raise ValueError("baud must be positive or None")
        if latency < 0:
            raise ValueError("latency must not be negative")
        self.baud = baud
        self.latency = latency
        self._byte_time = 10.0 / baud if baud else 0.0
        self._wake = re.compile(b"[" + re.escape(wake) + b"]") if wake else None
        # Each segment: [arrival of its first byte, data, bytes already taken].
        self._segments: deque[list] = deque()
        self._line_free = 0.0  # when the sender finishes the bytes put in so far
        self._next: float | None = None  # next_arrival(), cached until the next change
        self._next_known = True
        self.pending = 0

    def put(self, data: bytes, now: float) -> None:
        """Send *data* at *now* (it queues behind anything still being sent)."""
        if not data:
            return
        start = max(now, self._line_free)
        self._line_free = start + len(data) * self._byte_time
        first = start + self._byte_time + self.latency
        self._segments.append([first, bytes(data), 0])
        self.pending += len(data)
        self._next_known = False

    def take(self, now: float) -> bytes:
        """Every byte that has arrived by *now*, in order."""
        out: list[bytes] = []
        segments = self._segments
        self._next_known = False
        while segments:
            segment = segments[0]
            first, data, taken = segment
            if self._byte_time:
                bytes_in = (now - first) / self._byte_time + SLACK_BYTES
                end = min(len(data), int(bytes_in) + 1) if bytes_in >= 0 else 0
            else:
                end = len(data) if now >= first else 0
            if end <= taken:
                break
            out.append(data[taken:end])
            self.pending -= end - taken
            if end < len(data):
                segment[2] = end
                break
            segments.popleft()
        return b"".join(out)

    def next_arrival(self) -> float | None:
        """When the reader should next look (see the class docstring), or None."""
        if not self._next_known:
            self._next = self._find_next()
            self._next_known = True
        return self._next

    def _find_next(self) -> float | None:
        if not self._segments:
            return None
        if self._wake is None:
            first, _, taken = self._segments[0]
            return first + taken * self._byte_time
        for first, data, taken in self._segments:
            match = self._wake.search(data, taken)
            if match is not None:
                return first + match.start() * self._byte_time
        first, data, _ = self._segments[-1]
        return first + (len(data) - 1) * self._byte_time

    @property
    def busy_until(self) -> float:
        """When the sender finishes what was put in so far (earlier = idle)."""
        return self._line_free

    def horizon(self, now: float) -> float:
        """Bytes put in from *now* on cannot arrive before this time."""
        return max(now, self._line_free) + self._byte_time + self.latency

    def clear(self) -> None:
        """Lose everything in flight (the port was closed)."""
        self._segments.clear()
        self.pending = 0
        self._next, self._next_known = None, True
