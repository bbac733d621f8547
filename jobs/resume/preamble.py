"""The commands a resumed run sends before the file's lines (sans-IO: state in, text out).

A 3D printer (after a power cut the firmware knows nothing; after a worker crash it
may still be hot and homed, and the same commands are harmless):

    bed and chamber targets, then the hotends'     heat while the head is parked
    G92 Z<where it stopped>, G1 Z<+lift>           the nozzle is taken to be where
                                                   the print stopped: Z is not homed
                                                   (the part is on the bed) unless
                                                   the printer says to home it
    G28 X Y                                        home X and Y only
    M420 S1                                        if the file levelled the bed
    wait for the heaters
    T<tool>, G1 X Y over the part, G1 Z down       back to the resume point
    G92 E<the file's E at the line>                E as the file expects
    fans, settings, feedrate, modes                as the file left them

A GRBL machine: units and absolute moves, the work coordinate system, no G92 offset
(`G92.1`: a reset clears it, a worker's crash does not), homing when the machine
says to (`$H`), up to a safe height (above the highest Z the file went to so far),
over the point, the file's G92 offset again (`G92` with the point's numbers),
spindle on with a spin-up dwell, coolant, down at the file's feedrate, then the
file's modes and feedrate. An axis the file's coordinates lost before the line (a
G53 move in machine coordinates, G28/G30 to a stored position, a probe) is left to
the file's next move: no plunge to a depth that means something else.

Every line carries a comment saying why; the stream strips comments.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from jobs.resume.state import INCH

if TYPE_CHECKING:
    from jobs.resume.state import MachineState

#: Travel and Z feedrates of the preamble's own moves (mm/min).
TRAVEL_FEED = 3000.0
Z_FEED = 600.0
#: Seconds a spindle gets to reach its speed before the tool goes down.
SPIN_UP_SECONDS = 3.0


@dataclass(slots=True)
class ResumePoint:
    """Where a resumed run starts, and what the interrupted run left behind."""

    line: int
    state: MachineState
    #: The lowest Z the last commands before the stop went to: the nozzle is at
    #: least this high (the firmware may not have run every acknowledged move).
    stop_z: float
    home_z: bool = False
    lift: float = 5.0
    warnings: list[str] = field(default_factory=list)


def number(value: float) -> str:
    """A G-code number: up to five decimals, no trailing zeros."""
    text = f"{value:.5f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def build_preamble(point: ResumePoint) -> list[str]:
    """The preamble's lines, each with a comment for the operator."""
    if point.state.firmware == "grbl":
        return _cnc(point)
    return _fff(point)


def _fff(point: ResumePoint) -> list[str]:
    state = point.state
    x, y, z, e = state.position
    lines = [f"; resume at line {point.line + 1}, Z {number(z)} mm"]
    heaters = state.heaters
    if heaters.get("bed"):
        lines.append(f"M140 S{number(heaters['bed'])} ; bed target")
    if heaters.get("chamber"):
        lines.append(f"M141 S{number(heaters['chamber'])} ; chamber target")
    tools = sorted(k for k in heaters if k.startswith("tool") and heaters[k] > 0)
    for name in tools:
        lines.append(f"M104 T{name[4:]} S{number(heaters[name])} ; hotend target")
    lines += ["G21 ; millimetres", "G90 ; absolute moves", "M82 ; absolute E"]
    clear = max(point.stop_z, z) + point.lift
    if point.home_z:
        lines.append("G28 ; home every axis (the printer homes Z on resume)")
        lines.append(f"G1 Z{number(clear)} F{number(Z_FEED)} ; above the part")
    else:
        lines.append(
            f"G92 Z{number(point.stop_z)} ; the nozzle is where the print stopped"
        )
        lines.append(f"G1 Z{number(clear)} F{number(Z_FEED)} ; clear of the part")
        lines.append("G28 X Y ; home X and Y only: the part is on the bed")
    if state.levelling:
        lines.append("M420 S1 ; bed levelling on (the stored mesh: never probe now)")
    if heaters.get("bed"):
        lines.append(f"M190 S{number(heaters['bed'])} ; wait for the bed")
    if heaters.get("chamber"):
        lines.append(f"M191 S{number(heaters['chamber'])} ; wait for the chamber")
    for name in tools:
        lines.append(f"M109 T{name[4:]} S{number(heaters[name])} ; wait for the hotend")
    lines.append(f"T{state.tool} ; the active tool")
    if state.known[0] or state.known[1]:
        lines.append(
            f"G1 X{number(x)} Y{number(y)} F{number(TRAVEL_FEED)} ; over the point"
        )
    lines.append(f"G1 Z{number(z)} F{number(Z_FEED)} ; down to the resume height")
    lines.append(f"G92 E{number(e)} ; E as the file has it at this line")
    if state.retracted:
        lines.append("G10 ; the file had retracted the filament (firmware retraction)")
    for index, speed in sorted(state.fans.items()):
        lines.append(
            f"M106 P{index} S{number(speed)} ; fan" if speed > 0 else f"M107 P{index}"
        )
    # In the order the file last set them: a later one may override part of one
    # before it (`M204 P800 T1500`, then `M204 P900`).
    lines += [f"{text} ; as the file set it" for text in state.settings.values()]
    lines += _modes(state)
    return lines


def _cnc(point: ResumePoint) -> list[str]:
    state = point.state
    x, y, z, _ = state.position
    known_x, known_y, known_z, _ = state.known
    # Planning refuses a plan whose offsets cannot be set again (offsets_lost).
    offsets = [offset or 0.0 for offset in state.g92]
    lines = [f"; resume at line {point.line + 1}, Z {number(z)} mm"]
    lines += ["G21 ; millimetres", "G90 ; absolute moves", "G94 ; feed per minute"]
    lines.append(f"G{54 + state.coordinate_system} ; the file's work coordinates")
    # A reset clears GRBL's G92 offset, a worker's crash does not: cleared either
    # way, the preamble's moves are in the work coordinates alone, and the file's
    # offset is set again below once the tool is over a point it knows.
    lines.append("G92.1 ; no G92 offset until the file's own is set again")
    if point.home_z:
        lines.append("$H ; home (the machine homes on resume)")
    top = max(state.top, z + offsets[2]) if known_z else state.top
    safe = top + point.lift
    lines.append(f"G0 Z{number(safe)} ; a safe height above the work")
    over = [
        f"{letter}{number(value + offset)}"
        for letter, value, offset, known in zip(
            "XY", (x, y), offsets, (known_x, known_y), strict=False
        )
        if known
    ]
    if over:
        lines.append(f"G0 {' '.join(over)} ; over the point")
    if any(offsets):
        here = [
            f"{letter}{number(value)}"
            for letter, value, known in zip(
                "XY", (x, y), (known_x, known_y), strict=False
            )
            if known
        ]
        here.append(f"Z{number(safe - offsets[2])}")
        lines.append(f"G92 {' '.join(here)} ; the file's G92 offset again")
    if state.spindle in ("M3", "M4"):
        lines.append(f"{state.spindle} S{number(state.spindle_speed)} ; spindle on")
        lines.append(f"G4 P{number(SPIN_UP_SECONDS)} ; let it reach its speed")
    for coolant in state.coolant:
        lines.append(f"{coolant} ; coolant")
    if known_z:
        plunge = state.feedrate or Z_FEED
        lines.append(f"G1 Z{number(z)} F{number(plunge)} ; down to the resume depth")
    lines += _modes(state)
    return lines


def _modes(state: MachineState) -> list[str]:
    """The file's modes and feedrate, last (the preamble's moves used its own)."""
    lines = []
    unit = INCH if state.inches else 1.0
    if state.inches:
        lines.append("G20 ; inches, as the file")
    if not state.absolute:
        lines.append("G91 ; relative moves, as the file")
    if state.firmware == "grbl":
        if state.inverse_time:
            lines.append("G93 ; inverse time feed, as the file")
    elif not state.absolute_e and state.absolute:
        lines.append("M83 ; relative E, as the file")
    elif state.absolute_e and not state.absolute:
        lines.append("M82 ; absolute E, as the file")
    feed = number(state.feedrate / unit)
    if state.firmware == "grbl":
        motion = state.motion if state.motion in ("G0", "G1") else "G1"
        lines.append(
            f"{motion} F{feed} ; the file's motion mode and feedrate"
            if state.feedrate > 0 and not state.inverse_time
            else f"{motion} ; the file's motion mode"
        )
    elif state.feedrate > 0:
        lines.append(f"G1 F{feed} ; the file's feedrate")
    return lines
