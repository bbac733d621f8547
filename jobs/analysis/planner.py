"""The firmware's motion planner, modelled to tell how long moves take.

Moves become blocks as in Marlin's `planner.cpp`: each block has a length, an
acceleration, a nominal (cruise) speed and a highest entry speed set by its
corner with the block before: junction deviation (Marlin 2) or classic jerk (older
Marlin, Prusa firmware, RepRapFirmware; the same rules as PrusaSlicer's estimator).
Entry speeds are planned with a reverse then a forward pass, and every block takes
a trapezoidal speed profile: accelerate, cruise, decelerate.

Moves arrive in batches (numpy arrays) and the passes run on whole arrays. The
reverse pass `e[i] = min(m[i], e[i+1] + 2·a[i]·d[i])` unrolls to a suffix minimum
over prefix sums, and the forward pass to a prefix minimum, so neither needs a
Python loop. Like the firmware, the newest block is planned to end at rest; the
newest `WINDOW` blocks wait for more moves before they are timed, and the first of
them keeps the entry speed already given to it. `on_blocks(tags, seconds)` hears
the timed blocks in order, so the caller can add time up by file line. Speeds are
kept squared, as Marlin keeps them.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Callable

    from jobs.analysis.limits import MotionLimits

#: Blocks kept for look-ahead once older ones are timed (Marlin keeps 16).
WINDOW = 64
#: Moves gathered before they are planned (bounded memory, few numpy calls).
BATCH = 16384
#: Marlin's MINIMUM_PLANNER_SPEED (mm/s), squared: the slowest planned junction.
MIN_SPEED_SQ = 0.05**2


def trapezoid_seconds(
    distance: float, accel: float, entry_sq: float, nominal_sq: float, exit_sq: float
) -> float:
    """Time of one block: accelerate from entry, cruise, decelerate to exit."""
    return float(
        trapezoids(
            np.array([distance]),
            np.array([accel]),
            np.array([entry_sq]),
            np.array([nominal_sq]),
            np.array([exit_sq]),
        )[0]
    )


def trapezoids(
    distance: np.ndarray,
    accel: np.ndarray,
    entry_sq: np.ndarray,
    nominal_sq: np.ndarray,
    exit_sq: np.ndarray,
) -> np.ndarray:
    """Times of many blocks at once (see `trapezoid_seconds`)."""
    nominal_sq = np.maximum(nominal_sq, np.maximum(entry_sq, exit_sq))
    two_a = 2.0 * accel
    entry, leave, nominal = np.sqrt(entry_sq), np.sqrt(exit_sq), np.sqrt(nominal_sq)
    cruise = distance - (2.0 * nominal_sq - entry_sq - exit_sq) / two_a
    full = (2.0 * nominal - entry - leave) / accel + np.maximum(cruise, 0.0) / nominal
    # No room to reach the nominal speed: accelerate to where the ramps meet.
    meet = np.clip(
        (exit_sq - entry_sq + two_a * distance) / (2.0 * two_a), 0.0, distance
    )
    peak = np.sqrt(entry_sq + two_a * meet)
    short = (2.0 * peak - entry - leave) / accel
    return np.where(cruise >= 0.0, full, short)


class Planner:
    """Moves in (`add`, `move`), seconds out (through *on_blocks*), with look-ahead."""

    def __init__(
        self,
        limits: MotionLimits,
        on_blocks: Callable[[np.ndarray, np.ndarray], None],
    ) -> None:
        self.limits = limits
        self.on_blocks = on_blocks
        # Pending blocks, as lists of arrays: tag, distance, accel, nominal², max entry².
        self._parts: list[tuple[np.ndarray, ...]] = []
        self._pending = 0
        #: The previous block, for the next corner: its unit vector (deviation) or
        #: axis speeds (jerk), nominal speed² and safe speed (jerk).
        self._prev_vector: np.ndarray | None = None
        self._prev_nominal_sq = 0.0
        self._prev_safe = 0.0
        #: The entry speed² the first pending block must keep (already timed).
        self._fixed_entry: float | None = None

    def set_limits(self, limits: MotionLimits) -> None:
        """New limits (M201, M203, M204, M205...) apply to the moves after them."""
        self.limits = limits

    def move(
        self, tag: int, delta: tuple[float, float, float, float], feedrate: float
    ) -> None:
        """Queue one straight move by *delta* (mm, X Y Z E) at *feedrate* (mm/s)."""
        self.add(
            np.array([tag], np.int64),
            np.array([delta], np.float64),
            np.array([feedrate], np.float64),
        )

    def add(self, tags: np.ndarray, deltas: np.ndarray, feedrates: np.ndarray) -> None:
        """Queue moves: *deltas* is (n, 4) millimetres X Y Z E, *feedrates* mm/s."""
        from jobs.analysis import kernels  # numba: loaded by the first analysis only

        limits = self.limits
        deltas = np.ascontiguousarray(deltas, np.float64)
        distance, accel, feed = kernels.block_limits(
            deltas,
            np.ascontiguousarray(feedrates, np.float64),
            np.array(
                [
                    limits.travel_acceleration,
                    limits.print_acceleration,
                    limits.retract_acceleration,
                ],
                np.float64,
            ),
            np.array([limits.min_feedrate, limits.min_travel_feedrate], np.float64),
            np.array(limits.max_feedrate, np.float64),
            np.array(limits.max_acceleration, np.float64),
        )
        keep = distance >= 1e-9
        if not keep.all():
            tags, deltas = tags[keep], deltas[keep]
            distance, accel, feed = distance[keep], accel[keep], feed[keep]
        if not len(tags):
            return
        nominal_sq = feed * feed
        if limits.classic_jerk:
            max_entry = self._jerk_junctions(deltas, distance, feed)
        else:
            max_entry = self._deviation_junctions(deltas, distance, accel, nominal_sq)
        self._parts.append((tags, distance, accel, nominal_sq, max_entry))
        self._pending += len(tags)
        if self._pending >= BATCH + WINDOW:
            self._plan(keep=WINDOW)

    def _deviation_junctions(
        self,
        deltas: np.ndarray,
        distance: np.ndarray,
        accel: np.ndarray,
        nominal_sq: np.ndarray,
    ) -> np.ndarray:
        """Highest entry speeds² by junction deviation (Marlin 2)."""
        unit = deltas / distance[:, None]
        prev = np.empty_like(unit)
        prev[1:] = unit[:-1]
        prev_nominal = np.empty_like(nominal_sq)
        prev_nominal[1:] = nominal_sq[:-1]
        first_free = self._prev_vector is None or self._prev_nominal_sq < 1e-8
        prev[0] = 0.0 if self._prev_vector is None else self._prev_vector
        prev_nominal[0] = self._prev_nominal_sq
        self._prev_vector = unit[-1].copy()
        self._prev_nominal_sq = float(nominal_sq[-1])
        from jobs.analysis import kernels  # numba: loaded by the first analysis only

        limits = self.limits
        return kernels.deviation_junctions(
            unit,
            prev,
            accel,
            nominal_sq,
            prev_nominal,
            distance,
            np.array(limits.max_acceleration, np.float64),
            float(limits.junction_deviation),
            first_free,
        )

    def _jerk_junctions(
        self, deltas: np.ndarray, distance: np.ndarray, feed: np.ndarray
    ) -> np.ndarray:
        """Highest entry speeds² by classic jerk (Marlin 1.1, PrusaSlicer's model)."""
        jerks = np.array(self.limits.jerk)
        speeds = deltas / distance[:, None] * feed[:, None]
        safe = feed.copy()
        for axis, jerk in enumerate(jerks):
            # An axis faster than its jerk starts and stops at its jerk.
            over = np.abs(speeds[:, axis]) > jerk
            np.minimum(safe, np.where(over, jerk, np.inf), out=safe)
        prev = np.empty_like(speeds)
        prev[1:] = speeds[:-1]
        prev_feed = np.empty_like(feed)
        prev_feed[1:] = feed[:-1]
        prev_safe = np.empty_like(safe)
        prev_safe[1:] = safe[:-1]
        has_prev = self._prev_vector is not None
        prev[0] = self._prev_vector if has_prev else 0.0
        prev_feed[0] = math.sqrt(self._prev_nominal_sq) if has_prev else 0.0
        prev_safe[0] = self._prev_safe
        self._prev_vector = speeds[-1].copy()
        self._prev_nominal_sq = float(feed[-1] ** 2)
        self._prev_safe = float(safe[-1])
        larger = prev_feed > feed
        with np.errstate(divide="ignore", invalid="ignore"):
            smaller = np.where(larger, feed / prev_feed, prev_feed / feed)
        junction = np.where(larger, feed, prev_feed)
        factor = np.ones_like(feed)
        limited = np.zeros(len(feed), bool)
        for axis in range(4):
            leave = np.where(larger, prev[:, axis] * smaller, prev[:, axis])
            enter = speeds[:, axis]
            leave = np.where(limited, leave * factor, leave)
            enter = np.where(limited, enter * factor, enter)
            step = np.where(
                leave > enter,
                np.where(
                    (enter > 0) | (leave < 0), leave - enter, np.maximum(leave, -enter)
                ),
                np.where(
                    (enter < 0) | (leave > 0), enter - leave, np.maximum(-leave, enter)
                ),
            )
            jerk = jerks[axis]
            hit = step > jerk
            with np.errstate(divide="ignore", invalid="ignore"):
                factor = np.where(hit, factor * jerk / step, factor)
            limited |= hit
        junction = np.where(limited, junction * factor, junction)
        threshold = junction * 0.99
        junction = np.where(
            (prev_safe > threshold) & (safe > threshold), safe, junction
        )
        junction = np.where(prev_feed > 1e-4, junction, safe)
        return junction * junction

    def pause(self, tag: int, seconds: float) -> None:
        """The machine stands still for *seconds*: moves before it end at rest."""
        self.flush()
        if seconds > 0.0:
            self.on_blocks(np.array([tag], np.int64), np.array([seconds]))

    def flush(self) -> None:
        """Time every queued block; the next move starts from rest."""
        if self._pending:
            self._plan(keep=0)
        self._prev_vector = None
        self._prev_nominal_sq = 0.0
        self._prev_safe = 0.0
        self._fixed_entry = None

    def _plan(self, *, keep: int) -> None:
        """Plan the queued blocks to end at rest; time all but the newest *keep*."""
        tags, distance, accel, nominal_sq, max_entry = (
            np.concatenate(column) for column in zip(*self._parts, strict=True)
        )
        count = len(tags)
        if self._fixed_entry is not None:
            max_entry[0] = self._fixed_entry
        reach = 2.0 * accel * distance
        # Reverse pass: e[i] = min(m[i], e[i+1] + reach[i]), e[count] = rest.
        before = np.zeros(count + 1)
        np.cumsum(reach, out=before[1:])
        limits = np.empty(count + 1)
        limits[:count] = max_entry
        limits[count] = MIN_SPEED_SQ
        suffix = np.minimum.accumulate((limits + before)[::-1])[::-1]
        entry = suffix[:count] - before[:count]
        # Forward pass: f[i+1] = min(e[i+1], f[i] + reach[i]).
        prefix = np.minimum.accumulate(entry - before[:count])
        entry = prefix + before[:count]
        if self._fixed_entry is not None:
            entry[0] = self._fixed_entry
        done = count - keep
        exits = np.empty(count)
        exits[:-1] = entry[1:]
        exits[-1] = MIN_SPEED_SQ
        seconds = trapezoids(
            distance[:done], accel[:done], entry[:done], nominal_sq[:done], exits[:done]
        )
        self.on_blocks(tags[:done], seconds)
        if keep:
            self._parts = [
                (
                    tags[done:],
                    distance[done:],
                    accel[done:],
                    nominal_sq[done:],
                    max_entry[done:],
                )
            ]
            self._pending = keep
            self._fixed_entry = float(entry[done])
        else:
            self._parts = []
            self._pending = 0
            self._fixed_entry = None
