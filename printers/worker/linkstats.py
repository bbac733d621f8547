"""The link's figures (`Printer.link_stats`): counted as the loop goes, summed once a second.

The loop tells it what it wrote and read (one call per write and per read, not per
line); the protocol keeps its own counters (lines sent and acknowledged, resends,
timeouts, the ack round trip). Once a second `snapshot()` puts them together with
the rates over the last few seconds, in the shape the comment above
`Printer.link_stats` gives; the worker saves it with the printer's status.
"""

from __future__ import annotations

import time
from collections import deque
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from printers.protocol.link import LinkProtocol

__all__ = ["SNAPSHOT_SECONDS", "LinkStats"]

#: A snapshot at most this often (s): `Printer.link_stats` is saved no more often.
SNAPSHOT_SECONDS = 1.0
#: Rates (lines/s, link use) are taken over about this many seconds.
RATE_SECONDS = 5.0
#: An idle link's figures are refreshed this often (s) even when nothing moved.
IDLE_SECONDS = 10.0


class LinkStats:
    """Counts bytes both ways since the connect; `snapshot()` adds the rest."""

    def __init__(self, baud: int) -> None:
        #: Bytes a second the line carries (8N1: ten bits a byte).
        self.capacity = max(1, baud) / 10
        self.bytes_sent = 0
        self.bytes_received = 0
        self.connected_at: datetime | None = None
        self._next = 0.0
        #: (monotonic time, lines acknowledged, bytes sent) of recent snapshots.
        self._samples: deque[tuple[float, int, int]] = deque()
        self._last: dict[str, Any] = {}
        self._saved_at = 0.0

    def connected(self, now: float) -> None:
        """A new connection: the counters start again."""
        self.bytes_sent = self.bytes_received = 0
        self.connected_at = datetime.now(UTC)
        self._samples.clear()
        self._next = now
        self._last = {}

    def snapshot(self, now: float, protocol: LinkProtocol) -> dict[str, Any] | None:
        """The figures, when a second has passed and they are worth saving; else None.

        An idle link (nothing sent or acknowledged, its rates already at zero) is
        saved again only every IDLE_SECONDS, so idle printers do not write a row a
        second for nothing.
        """
        if now < self._next or self.connected_at is None:
            return None
        self._next = now + SNAPSHOT_SECONDS
        acked = int(getattr(protocol, "lines_acked", 0))
        samples = self._samples
        samples.append((now, acked, self.bytes_sent))
        while len(samples) > 2 and now - samples[1][0] >= RATE_SECONDS:
            samples.popleft()
        then, acked_then, sent_then = samples[0]
        span = now - then
        lines_per_s = (acked - acked_then) / span if span > 0 else 0.0
        link_use = (self.bytes_sent - sent_then) / span / self.capacity if span else 0.0
        stats = {
            "lines_sent": int(getattr(protocol, "lines_sent", 0)),
            "lines_acked": acked,
            "resends": int(getattr(protocol, "resends", 0)),
            "timeouts": int(getattr(protocol, "timeouts", 0)),
            "bytes_sent": self.bytes_sent,
            "bytes_received": self.bytes_received,
            "rtt_ms": round(float(getattr(protocol, "rtt", 0.0)) * 1000, 3),
            "lines_per_s": round(lines_per_s, 1),
            "link_use": round(min(1.0, max(0.0, link_use)), 3),
        }
        moved = {k: v for k, v in stats.items() if k != "rtt_ms"}
        last = {k: v for k, v in self._last.items() if k in moved}
        idle = moved == last and not lines_per_s and not link_use
        if idle and now - self._saved_at < IDLE_SECONDS:
            return None
        self._last, self._saved_at = stats, now
        return {
            **stats,
            "cpu_s": round(time.process_time(), 3),
            "at": datetime.now(UTC).isoformat(),
            "connected_at": self.connected_at.isoformat(),
        }
