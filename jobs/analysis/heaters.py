"""A simple model of the heaters, to tell how long a file waits for them.

Each heater moves toward its target at a steady rate (°C/s up, and a slower one
down), starting from the room's temperature. Setting a target (M104, M140) starts
it moving while the print goes on; a wait (M109, M190, M116) lasts until the
heater is there. The firmware's own control loop overshoots and settles; a steady
rate is close enough for minutes of heating, and it is kept apart from the motion
time so the motion model can be checked alone.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from jobs.analysis.limits import MotionLimits


class HeaterModel:
    """Heaters by name ("tool0", "bed"), each [temperature, target, as of when]."""

    def __init__(self, limits: MotionLimits) -> None:
        self.limits = limits
        self._heaters: dict[str, list[float]] = {}

    def set_target(self, name: str, target: float | None, now: float) -> None:
        """*name* heads for *target* from *now* (seconds into the print)."""
        heater = self._heater(name, now)
        if target is not None:
            heater[1] = target

    def wait(self, name: str, now: float, *, either: bool) -> float:
        """Seconds until *name* reaches its target (cooling too when *either*, as
        M109 R does); the heater is there afterwards."""
        heater = self._heater(name, now)
        temp, target = heater[0], heater[1]
        seconds = 0.0
        if target > temp:
            seconds = (target - temp) / self._rate(name, heating=True)
        elif either and temp > target:
            seconds = (temp - target) / self._rate(name, heating=False)
        if target > temp or either:
            heater[0] = target
        heater[2] = now + seconds
        return seconds

    def wait_all(self, now: float) -> float:
        """M116: seconds until every heater that heats is at its target."""
        waits = [self.wait(name, now, either=False) for name in list(self._heaters)]
        longest = max(waits, default=0.0)
        for heater in self._heaters.values():
            heater[2] = now + longest
        return longest

    def _heater(self, name: str, now: float) -> list[float]:
        heater = self._heaters.setdefault(name, [self.limits.ambient, 0.0, now])
        self._advance(name, heater, now)
        return heater

    def _rate(self, name: str, *, heating: bool) -> float:
        limits = self.limits
        if not heating:
            return max(limits.cool_rate, 1e-3)
        rate = limits.bed_heat_rate if name == "bed" else limits.hotend_heat_rate
        return max(rate, 1e-3)

    def _advance(self, name: str, heater: list[float], now: float) -> None:
        """Move the heater's temperature toward its target for the time gone by."""
        temp, target, since = heater
        gone = max(0.0, now - since)
        room = self.limits.ambient
        if target > temp:
            temp = min(target, temp + self._rate(name, heating=True) * gone)
        elif temp > max(target, room):
            temp = max(target, room, temp - self._rate(name, heating=False) * gone)
        heater[0], heater[2] = temp, now
