"""A heater that moves linearly towards its target: enough for M104/M109/M190 timing."""

from __future__ import annotations

__all__ = ["AMBIENT", "Heater"]

AMBIENT = 21.0
#: Marlin's TEMP_WINDOW / TEMP_BED_WINDOW: close enough to count as reached.
WINDOW = 1.0
#: Rounding left by stepping a heater to its own reach time (°C): a heater this
#: close to the window is in it, or a wait would ask for the time it is at, for ever.
SLACK = 1e-6


class Heater:
    """Temperature as a function of time; rates are °C per second (0 = instant)."""

    __slots__ = ("_clock", "cool_rate", "heat_rate", "target", "temp")

    def __init__(self, heat_rate: float, cool_rate: float, now: float) -> None:
        self.temp = AMBIENT
        self.target = 0.0
        self.heat_rate = heat_rate
        self.cool_rate = cool_rate
        self._clock = now

    @property
    def goal(self) -> float:
        return self.target if self.target > 0 else AMBIENT

    @property
    def power(self) -> int:
        """PWM as Marlin reports it after `@:` (0..127)."""
        return 127 if self.target > 0 and self.temp < self.target - WINDOW else 0

    def update(self, now: float) -> None:
        elapsed = max(0.0, now - self._clock)
        self._clock = max(self._clock, now)
        goal = self.goal
        rate = self.heat_rate if goal > self.temp else self.cool_rate
        if rate <= 0:
            self.temp = goal
            return
        step = rate * elapsed
        if abs(goal - self.temp) <= step:
            self.temp = goal
        else:
            self.temp += step if goal > self.temp else -step

    def set_target(self, target: float, now: float) -> None:
        self.update(now)
        self.target = max(0.0, target)

    def reached(self, *, heating_only: bool) -> bool:
        """M109 S / M190 S wait only while heating; R waits for cooling too."""
        if self.target <= 0:
            return True
        if heating_only and self.temp >= self.target:
            return True
        return abs(self.temp - self.target) <= WINDOW + SLACK

    def reach_time(self) -> float:
        """When `reached()` will hold if nothing changes (valid after `update`)."""
        gap = abs(self.goal - self.temp) - WINDOW
        rate = self.heat_rate if self.goal > self.temp else self.cool_rate
        if gap <= SLACK or rate <= 0:
            return self._clock
        return self._clock + gap / rate
