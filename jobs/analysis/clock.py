"""The print's time as the planner times its blocks: motion and heating totals,
the timeline's marks, and the time each layer starts.

Blocks are timed in file order but later than they are read (the planner looks
ahead), so a mark or a layer waits until the first block at or after its command
is timed: its time is everything timed before that block.
"""

from __future__ import annotations

import bisect
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from jobs.analysis.result import Layer, Timeline


class Clock:
    def __init__(self, timeline: Timeline) -> None:
        self.timeline = timeline
        self.motion = 0.0
        self.heating = 0.0
        self._layers: list[Layer] = []

    @property
    def _next_mark(self) -> int:
        return len(self.timeline.seconds) * self.timeline.stride

    @property
    def now(self) -> float:
        """Seconds timed so far (motion and heating)."""
        return self.motion + self.heating

    def timed(self, tags: np.ndarray, seconds: np.ndarray) -> None:
        """The planner timed blocks of commands *tags* (in order)."""
        before, last = self.now, int(tags[-1])
        waiting = self._layers and self._layers[0].line <= last
        if last >= self._next_mark or waiting:
            ahead = np.zeros(len(seconds) + 1)
            np.cumsum(seconds, out=ahead[1:])
            if last >= self._next_mark:
                marks = np.arange(self._next_mark, last + 1, self.timeline.stride)
                for value in ahead[np.searchsorted(tags, marks)]:
                    self._mark(before + float(value))
                self.timeline.thin()
            while self._layers and self._layers[0].line <= last:
                layer = self._layers.pop(0)
                at = int(np.searchsorted(tags, layer.line))
                layer.time = round(before + float(ahead[at]), 2)
        self.motion += float(seconds.sum())

    def heat(self, index: int, seconds: float) -> None:
        """A heater wait of *seconds* at command *index* (moves before it are timed)."""
        self.timed(np.array([index]), np.zeros(1))
        self.heating += seconds

    def layer_starts(self, layer: Layer) -> None:
        """Give *layer* its time once its first command is timed."""
        # In line order, as they are timed: a sort each time was quadratic in
        # the layers (100,000 rising layers took two minutes).
        bisect.insort(self._layers, layer, key=lambda item: item.line)

    def finish(self, commands: int) -> None:
        """Nothing more to time: the marks up to the file's end and the layers still
        waiting take the total."""
        total = self.now
        while self._next_mark <= commands:
            self._mark(total)
        self.timeline.thin()
        for layer in self._layers:
            layer.time = round(total, 2)
        self._layers = []

    def _mark(self, before: float) -> None:
        self.timeline.seconds.append(round(before, 2))
        self.timeline.heating.append(round(self.heating, 2))
