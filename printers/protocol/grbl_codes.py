"""What GRBL 1.1's codes and commands mean: errors, alarms, realtime bytes, EEPROM."""

from __future__ import annotations

import re

from printers.protocol.checksum import clean_line

__all__ = [
    "ALARMS",
    "ERRORS",
    "JOG_CANCEL",
    "REALTIME_COMMANDS",
    "alarm_meaning",
    "error_meaning",
    "jog_line",
    "line_traits",
]

#: `$n=`, `$Nn=`, `$I=`, `$RST=`: system commands that store something.
_SETTING_WRITE = re.compile(r"\$(\d+|N\d*|I|RST)=", re.IGNORECASE)
#: One G-code word, letter and number, in a line without spaces.
_WORD = re.compile(r"([A-Z])([-+]?\d*\.?\d*)")
#: Every G4, G10, G28.1 and G30.1 matches (spaces taken out first): a line that
#: does not is neither an EEPROM write nor a dwell, without reading its words.
_MAYBE_WRITE_OR_DWELL = re.compile(r"G[-+]?0*(?:4|10|28\.|30\.)", re.IGNORECASE)


#: `error:N` replies: the line was refused and did nothing.
ERRORS: dict[int, str] = {
    1: "a word is missing its letter",
    2: "a number is missing or badly written",
    3: "'$' command not recognised",
    4: "a value that must be positive is negative",
    5: "homing is disabled in the settings",
    6: "the step pulse must be at least 3 microseconds",
    7: "settings could not be read and were reset to defaults",
    8: "'$' commands are only allowed while the machine is idle",
    9: "G-code is locked while in alarm or jogging",
    10: "soft limits need homing to be enabled",
    11: "line longer than GRBL's line buffer",
    12: "this setting would push the step rate too high",
    13: "the safety door is open",
    14: "build info or startup line too long to store",
    15: "jog target lies outside the machine travel",
    16: "jog command lacks '=' or holds a forbidden word",
    17: "laser mode needs PWM spindle output",
    18: "unused code (not defined by GRBL 1.1)",
    19: "unused code (not defined by GRBL 1.1)",
    20: "unsupported G-code command",
    21: "two commands of the same modal group in one line",
    22: "no feed rate has been set",
    23: "this command needs a whole number",
    24: "two commands in one line both want the axis words",
    25: "the same word appears twice in one line",
    26: "this command needs axis words and none were given",
    27: "invalid line number",
    28: "a required value word is missing",
    29: "G59.1 to G59.3 work offsets are not supported",
    30: "G53 works only with G0 or G1",
    31: "axis words given but nothing in the line uses them",
    32: "an arc needs at least one axis word in its plane",
    33: "the motion target is invalid",
    34: "invalid arc radius",
    35: "an arc needs at least one offset word in its plane",
    36: "value words given that nothing uses",
    37: "G43.1 offset is not on the tool length axis",
    38: "tool number is above the supported maximum",
}

#: `ALARM:N` pushes: motion is locked until `$X` (unlock) or `$H` (home).
ALARMS: dict[int, str] = {
    1: "hard limit hit; position is likely lost, home again",
    2: "soft limit: the target is outside the machine travel",
    3: "reset during motion; position is lost, home again",
    4: "probe was already triggered before probing started",
    5: "probe never touched within the programmed distance",
    6: "homing stopped by a reset",
    7: "homing stopped because the safety door opened",
    8: "homing could not pull off the limit switch",
    9: "homing could not find the limit switch",
    10: "homing could not find the second switch of a dual axis",
}


#: Realtime commands: GRBL acts on them on arrival; they never enter its RX buffer.
REALTIME_COMMANDS: dict[str, str] = {
    "?": "status report",
    "!": "feed hold",
    "~": "cycle start",
    "\x18": "soft reset",
    "\x84": "safety door",
    "\x85": "jog cancel",
    "\x90": "feed override 100%",
    "\x91": "feed override +10%",
    "\x92": "feed override -10%",
    "\x93": "feed override +1%",
    "\x94": "feed override -1%",
    "\x95": "rapid override 100%",
    "\x96": "rapid override 50%",
    "\x97": "rapid override 25%",
    "\x98": "unassigned override",
    "\x99": "spindle override 100%",
    "\x9a": "spindle override +10%",
    "\x9b": "spindle override -10%",
    "\x9c": "spindle override +1%",
    "\x9d": "spindle override -1%",
    "\x9e": "spindle stop",
    "\xa0": "flood coolant toggle",
    "\xa1": "mist coolant toggle",
}


#: Jog cancel: stops a `$J=` jog (and only a jog), never enters the RX buffer.
JOG_CANCEL = "\x85"


def jog_line(moves: dict[str, float], feed: float, *, relative: bool = True) -> str:
    """`$J=G91 X10.000 F600`: a jog GRBL runs in its Jog state, cancelled by 0x85.

    *moves* maps axes (X, Y, Z, A, B, C) to mm; ValueError for anything GRBL would
    refuse (no axis, an unknown axis, a feed that is not positive).
    """
    axes = {axis.upper(): value for axis, value in moves.items()}
    unknown = sorted(set(axes) - set("XYZABC"))
    if unknown:
        raise ValueError(f"cannot jog axis {', '.join(unknown)}: GRBL jogs X Y Z A B C")
    if not axes:
        raise ValueError("a jog needs at least one axis")
    if not feed > 0:
        raise ValueError(f"a jog needs a positive feed rate (mm/min), not {feed}")
    words = " ".join(f"{axis}{value:.3f}" for axis, value in axes.items())
    return f"$J={'G91' if relative else 'G90'} {words} F{feed:g}"


def error_meaning(code: int) -> str:
    """Short English meaning of `error:<code>`."""
    return ERRORS.get(code, f"unknown error code {code}")


def alarm_meaning(code: int) -> str:
    """Short English meaning of `ALARM:<code>`."""
    return ALARMS.get(code, f"unknown alarm code {code}")


def line_traits(text: str) -> tuple[bool, float]:
    """Whether one line writes GRBL's EEPROM, and the seconds it dwells, its words
    read once (the protocol asks both of every line it sends).

    EEPROM writes are `$n=`, `$Nn=`, `$I=`, `$RST=`, G10 L2/L20, G28.1 and G30.1:
    GRBL turns its RX interrupt off while it writes, bytes arriving then are lost,
    so these commands must travel alone (send-response). A `G4 P<s>` line dwells
    P seconds (GRBL reads P as seconds); other lines 0.
    """
    stripped = text.lstrip()
    if stripped.startswith("$"):
        return _SETTING_WRITE.match(stripped) is not None, 0.0
    if _MAYBE_WRITE_OR_DWELL.search(text.replace(" ", "")) is None:
        return False, 0.0
    words = _words(text)
    g_codes = {value for letter, value in words if letter == "G"}
    writes = bool(g_codes & {28.1, 30.1}) or (
        10 in g_codes
        and any(letter == "L" and value in (2, 20) for letter, value in words)
    )
    if 4 not in g_codes:
        return writes, 0.0
    return writes, max([0.0, *(value for letter, value in words if letter == "P")])


def _words(text: str) -> list[tuple[str, float]]:
    """G-code words of *text* as (letter, value); spaces and comments ignored."""
    body = clean_line(text).replace(" ", "").upper()
    words = []
    for letter, number in _WORD.findall(body):
        try:
            words.append((letter, float(number)))
        except ValueError:
            continue
    return words
