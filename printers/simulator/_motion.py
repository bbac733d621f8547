"""The planner both firmware models share: a ring of timed moves run one after another."""

from __future__ import annotations

import math
from collections import deque

__all__ = ["Planner", "distance"]

#: Times closer than this count as equal (float sums of move durations drift).
EPSILON = 1e-9


def distance(start: tuple[float, ...], end: tuple[float, ...]) -> float:
    """Straight-line length between two points of the same dimension."""
    return math.dist(start, end)


class Planner:
    """Moves queued for the steppers; the head one runs, the others wait their turn.

    Like Marlin's and GRBL's block rings, one slot of *blocks* stays empty, so
    `capacity` is `blocks - 1` (GRBL's idle `Bf:15,...`, Marlin's `P15`). A block
    is (seconds at 100 % speed, target, rapid). Time passes only through
    `advance(now)`; everything else takes `now` so it can advance first.
    """

    def __init__(self, blocks: int, origin: tuple[float, ...]) -> None:
        self.capacity = max(1, blocks - 1)
        self._blocks: deque[tuple[float, tuple[float, ...], bool]] = deque()
        self._done = 0.0  # seconds at 100 % of the head block already run
        self._clock = 0.0  # when `_done` was last brought up to date
        self._start = origin  # where the head block started
        self._end = origin  # target of the last block queued
        self.held = False
        self.feed_factor = 1.0
        self.rapid_factor = 1.0

    def __len__(self) -> int:
        return len(self._blocks)

    @property
    def free(self) -> int:
        return self.capacity - len(self._blocks)

    def has_room(self) -> bool:
        return len(self._blocks) < self.capacity

    def idle(self) -> bool:
        return not self._blocks

    @property
    def end(self) -> tuple[float, ...]:
        """Where the machine will be once every queued block has run."""
        return self._end

    def advance(self, now: float) -> None:
        """Run blocks up to *now*; a finished block leaves the ring."""
        if self.held or not self._blocks:
            self._clock = max(self._clock, now)
            return
        budget = now - self._clock
        if budget <= 0:
            return
        self._clock = now
        blocks = self._blocks
        while blocks:
            seconds, target, rapid = blocks[0]
            speed = self.rapid_factor if rapid else self.feed_factor
            left = (seconds - self._done) / speed
            if budget < left - EPSILON:
                self._done += budget * speed
                return
            budget -= left
            blocks.popleft()
            self._done = 0.0
            self._start = target

    def add(
        self, seconds: float, target: tuple[float, ...], now: float, *, rapid: bool
    ) -> None:
        """Queue a move; the caller checked `has_room()`. Instant moves skip an idle ring."""
        self.advance(now)
        self._end = target
        if seconds <= 0 and not self._blocks:
            self._start = target
            return
        self._blocks.append((seconds, target, rapid))

    def retime(self, seconds: list[float]) -> None:
        """The last queued blocks take *seconds* (oldest first): the look-ahead found
        their speeds again. The running head block keeps its time."""
        blocks = self._blocks
        count = min(len(seconds), len(blocks) - 1)  # never the head block
        for offset in range(1, count + 1):
            _, target, rapid = blocks[-offset]
            blocks[-offset] = (seconds[-offset], target, rapid)

    def next_deadline(self) -> float | None:
        """When the head block finishes, or None while idle or held."""
        if self.held or not self._blocks:
            return None
        seconds, _, rapid = self._blocks[0]
        speed = self.rapid_factor if rapid else self.feed_factor
        return self._clock + (seconds - self._done) / speed

    def position(self, now: float) -> tuple[float, ...]:
        """Where the machine is at *now*, between the head block's start and target."""
        self.advance(now)
        if not self._blocks:
            return self._start
        seconds, target, _ = self._blocks[0]
        share = self._done / seconds if seconds > 0 else 1.0
        return tuple(
            a + (b - a) * share for a, b in zip(self._start, target, strict=True)
        )

    def clear(self, now: float) -> tuple[float, ...]:
        """Drop every block (quickstop, reset); returns where the machine stopped."""
        stopped = self.position(now)
        self._blocks.clear()
        self._done = 0.0
        self._start = self._end = stopped
        return stopped

    def set_origin(self, position: tuple[float, ...]) -> None:
        """Declare where an idle machine is (homing, G92 with nothing queued)."""
        if not self._blocks:
            self._start = position
        self._end = position

    def hold(self, now: float, *, held: bool) -> None:
        """Freeze (feed hold) or release the head block."""
        self.advance(now)
        self.held = held
        self._clock = now

    def set_speed(self, now: float, *, feed: float, rapid: float) -> None:
        """Feed/rapid overrides as factors of programmed speed (1.0 = 100 %)."""
        self.advance(now)
        self.feed_factor = max(feed, 0.01)
        self.rapid_factor = max(rapid, 0.01)
