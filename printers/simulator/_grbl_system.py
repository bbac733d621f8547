"""GRBL 1.1h's `$` commands, settings, override bytes and status report, for the GRBL model."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from printers.simulator.grbl import GrblFirmware, Job

__all__ = ["DEFAULTS", "OVERRIDES", "run_command", "status_fields"]

#: 1.1h defaults, except $10=3 (report MPos and Bf:) and $22=1 (homing on,
#: without HOMING_INIT_LOCK, so the controller still boots Idle).
DEFAULTS: dict[int, float] = {
    0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 3, 11: 0.010, 12: 0.002, 13: 0,
    20: 0, 21: 0, 22: 1, 23: 0, 24: 25.0, 25: 500.0, 26: 250, 27: 1.0,
    30: 1000, 31: 0, 32: 0,
    100: 250.0, 101: 250.0, 102: 250.0, 110: 500.0, 111: 500.0, 112: 500.0,
    120: 10.0, 121: 10.0, 122: 10.0, 130: 200.0, 131: 200.0, 132: 200.0,
}  # fmt: skip
_INTEGER = {0, 1, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 26, 30, 31, 32}

#: Override bytes: (attribute, value, relative).
OVERRIDES: dict[int, tuple[str, int, bool]] = {
    0x90: ("_feed_ov", 100, False), 0x91: ("_feed_ov", 10, True),
    0x92: ("_feed_ov", -10, True), 0x93: ("_feed_ov", 1, True),
    0x94: ("_feed_ov", -1, True),
    0x95: ("_rapid_ov", 100, False), 0x96: ("_rapid_ov", 50, False),
    0x97: ("_rapid_ov", 25, False),
    0x99: ("_spindle_ov", 100, False), 0x9A: ("_spindle_ov", 10, True),
    0x9B: ("_spindle_ov", -10, True), 0x9C: ("_spindle_ov", 1, True),
    0x9D: ("_spindle_ov", -1, True),
    # Spindle stop and the coolant toggles are accepted and change nothing here.
    0x9E: ("_spindle_ov", 0, True), 0xA0: ("_feed_ov", 0, True),
    0xA1: ("_feed_ov", 0, True),
}  # fmt: skip

HELP = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]"
_SETTING = re.compile(r"(\d+(?:\.\d*)?)(=?)(.*)")
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)")


def run_command(fw: GrblFirmware, line: str, now: float) -> int | Job:
    """Run a `$` line: GRBL's error code, 0 for ok, or a job that ends with the code."""
    key = line[1:]
    if not key:
        fw.print_lines(HELP)
        return 0
    if key.startswith("J="):
        if fw.state not in ("Idle", "Jog"):
            return 8
        action = fw.gcode.jog(key[2:])
        return action if isinstance(action, int) else fw.play([action], now, jog=True)
    if key[0] in "$GCX":
        return 3 if len(key) > 1 else _anytime(fw, key, now)
    if fw.state not in ("Idle", "Alarm"):
        return 8  # needs Idle (EEPROM, homing)
    if key == "#":
        _print_parameters(fw)
        return 0
    if key == "H":
        return 5 if not fw.settings[22] else fw.home(now)
    if key == "SLP":
        fw.print_lines("[MSG:Sleeping]")
        fw.state = "Sleep"
        return 0
    return _stored(fw, key, now)


def _anytime(fw: GrblFirmware, key: str, now: float) -> int:
    """`$$`, `$G`, `$C`, `$X`: allowed in (almost) any state."""
    if key == "G":
        fw.print_lines(f"[{fw.gcode.modes()}]")
    elif key == "$":
        if fw.state in ("Run", "Home") or fw.state.startswith("Hold"):
            return 8
        fw.print_lines(
            *(f"${n}={_format(n, v)}" for n, v in sorted(fw.settings.items()))
        )
    elif key == "C":
        if fw.state == "Check":
            fw.print_lines("[MSG:Disabled]")
            fw.reset_after_ok = True
        elif fw.state != "Idle":
            return 8
        else:
            fw.state = "Check"
            fw.print_lines("[MSG:Enabled]")
    elif fw.state == "Alarm":  # $X
        fw.print_lines("[MSG:Caution: Unlocked]")
        fw.state = "Idle"
    return 0


def _stored(fw: GrblFirmware, key: str, now: float) -> int | Job:
    """Build info, startup lines, restore and settings: all EEPROM."""
    eeprom = [("eeprom",)]
    if key == "I":
        _print_build_info(fw)
        return 0
    if key.startswith("I="):
        return fw.play(eeprom, now)
    if key.startswith("RST="):
        if key[4:] not in ("$", "#", "*"):
            return 3
        if key[4:] in ("$", "*"):
            fw.settings = dict(DEFAULTS)
        if key[4:] in ("#", "*"):
            fw.gcode.offsets = [[0.0, 0.0, 0.0] for _ in range(6)]
        fw.print_lines("[MSG:Restoring defaults]")
        fw.reset_after_ok = True
        return fw.play(eeprom, now)
    if key == "N":
        fw.print_lines(*(f"$N{i}={text}" for i, text in enumerate(fw.startup_lines)))
        return 0
    if key.startswith("N") and key[1:2].isdigit() and "=" in key:
        if fw.state != "Idle":
            return 8
        index = int(key[1])
        if index > 1 or key[2] != "=":
            return 3
        fw.startup_lines[index] = key[3:]
        return fw.play(eeprom, now)
    error = _store_setting(fw, key)
    return error if error else fw.play(eeprom, now)


def _store_setting(fw: GrblFirmware, key: str) -> int:
    match = _SETTING.fullmatch(key)
    if match is None:
        return 2  # bad number format
    number, equals, value = match.groups()
    if not equals or number != str(int(float(number))):
        return 3
    if _NUMBER.fullmatch(value) is None:
        return 2
    setting, new = int(number), float(value)
    if setting not in fw.settings:
        return 3  # invalid statement
    if new < 0:
        return 4
    if setting == 0 and new < 3:
        return 6  # step pulse must be at least 3 microseconds
    if setting == 20 and new and not fw.settings[22]:
        return 10  # soft limits need homing
    fw.settings[setting] = int(new) if setting in _INTEGER else new
    fw.gcode.max_rates = tuple(fw.settings[k] for k in (110, 111, 112))
    return 0


def status_fields(
    fw: GrblFirmware,
    position: tuple[float, ...],
    rate: float,
    overrides: tuple[int, int, int],
    count: int,
) -> list[str]:
    """The fields of a `?` report; $10 picks MPos/WPos and Bf:. WCO and Ov come
    every tenth report, as GRBL refreshes them only now and then."""
    mask = int(fw.settings[10])
    wco = fw.gcode.work_offset()
    fields = [fw.state]
    if mask & 1:
        fields.append("MPos:" + _xyz(list(position)))
    else:
        fields.append(
            "WPos:" + _xyz([p - o for p, o in zip(position, wco, strict=True)])
        )
    if mask & 2:
        fields.append(f"Bf:{fw.planner.free},{fw.rx_free}")
    speed = fw.gcode.speed if fw.gcode.spindle in (3, 4) else 0.0
    fields.append(f"FS:{rate:.0f},{speed:.0f}")
    if count % 10 == 0:
        fields.append("WCO:" + _xyz(wco))
    elif count % 10 == 1:
        fields.append("Ov:" + ",".join(str(v) for v in overrides))
    return fields


def _print_build_info(fw: GrblFirmware) -> None:
    """`$I`: grbl 1.1 `[OPT:letters,blocks,rx]`; grblHAL adds axes and its name."""
    blocks, rx = fw.planner.capacity, fw.rx_buffer
    if fw.variant == "grblhal":
        fw.print_lines(
            "[VER:1.1f.20231210:]",
            f"[OPT:VNMSL,{blocks},{rx},3,0]",
            "[NEWOPT:ENUMS,RT+,HOME,SED]",
            "[FIRMWARE:grblHAL]",
        )
    else:
        fw.print_lines("[VER:1.1h.20190825:]", f"[OPT:V,{blocks},{rx}]")


def _print_parameters(fw: GrblFirmware) -> None:
    gcode = fw.gcode
    lines = [f"[G{54 + i}:{_xyz(offset)}]" for i, offset in enumerate(gcode.offsets)]
    lines += [f"[G28:{_xyz(gcode.g28)}]", f"[G30:{_xyz(gcode.g30)}]"]
    lines += [f"[G92:{_xyz(gcode.g92)}]", "[TLO:0.000]", "[PRB:0.000,0.000,0.000:0]"]
    fw.print_lines(*lines)


def _format(number: int, value: float) -> str:
    return str(int(value)) if number in _INTEGER else f"{value:.3f}"


def _xyz(values: list[float]) -> str:
    return ",".join(f"{v:.3f}" for v in values)
