"""GRBL's realtime bytes in the simulator: picked off as they arrive, never queued."""

from __future__ import annotations

from typing import TYPE_CHECKING

from printers.simulator import _grbl_system as system

if TYPE_CHECKING:
    from printers.simulator.grbl import GrblFirmware


def act(fw: GrblFirmware, byte: int, now: float) -> None:
    """Do what one realtime byte asks, at *now*."""
    if byte == 0x18:
        fw.soft_reset(now)
    elif byte == 0x3F:
        fw._status(now)
    elif fw._locked:
        return
    elif byte == 0x21:
        feed_hold(fw, now)
    elif byte == 0x7E:
        cycle_start(fw, now)
    elif byte == 0x85:
        if fw.state == "Jog":
            fw._stop_motion(now)
            fw.state = "Idle"
    elif byte == 0x84:
        fw.planner.hold(now, held=True)
        fw.state = "Door:0"
    else:
        override(fw, byte, now)


def feed_hold(fw: GrblFirmware, now: float) -> None:
    """`!`: decelerate to a hold (a jog is cancelled instead)."""
    fw._update_state()
    if fw.state == "Jog":
        fw._stop_motion(now)
        fw.state = "Idle"
    elif fw.state in ("Idle", "Run"):
        fw.planner.hold(now, held=True)
        fw.state = "Hold:0"


def cycle_start(fw: GrblFirmware, now: float) -> None:
    """`~`: leave a hold or a closed door."""
    if fw.state.startswith(("Hold", "Door")):
        fw.planner.hold(now, held=False)
        fw.state = "Idle" if fw.planner.idle() else "Run"


def override(fw: GrblFirmware, byte: int, now: float) -> None:
    """0x90-0x9D: feed, rapid and spindle overrides, clamped as GRBL clamps them."""
    change = system.OVERRIDES.get(byte)
    if change is None:
        return  # unknown extended byte: thrown away, as GRBL does
    kind, value, relative = change
    current = getattr(fw, kind)
    new = current + value if relative else value
    low, high = (25, 100) if kind == "_rapid_ov" else (10, 200)
    setattr(fw, kind, min(max(new, low), high))
    fw.planner.set_speed(now, feed=fw._feed_ov / 100, rapid=fw._rapid_ov / 100)
    fw._reports = 1  # the next report carries Ov:
