"""The machine's state at any line of a file, rebuilt by reading the file to it (sans-IO).

    reader = StateReader(firmware="marlin")
    for text in commands:          # cleaned commands, as the stream sends them
        reader.feed(text)
    reader.state                   # what the firmware would hold after them

What a resume needs to put back, and nothing else: the modes (units, absolute or
relative axes and E, GRBL's work coordinate system and feed mode), the logical
position (as G92 left it) and E, the feedrate, heater targets, fans, the tool,
and the last of each setting command (acceleration, speed and flow factors,
linear advance...) to replay. Heaters and fans are kept by code and index, so a
resume sends one command for each; settings by code, the tool or extruder they
name, and the words they set (`_setting`). Positions are millimetres,
whatever units the file uses.
"""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass, field
from typing import Any

INCH = 25.4
_WORD = re.compile(r"([A-Z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")
_AXES = "XYZE"

#: Settings a resume replays as the file last gave them (the code, then the word
#: that says which heater, fan or tool it is for).
REPLAYED = frozenset(
    {
        "M201", "M203", "M204", "M205", "M207", "M208", "M209", "M220", "M221",
        "M566", "M572", "M593", "M900",
    }
)  # fmt: skip
#: The word of a replayed setting that says which tool or extruder it is for.
SELECTORS = {"M221": "T", "M900": "T", "M572": "D"}
#: Heater targets: code -> (the heater's name, waits).
HEATERS = {
    "M104": ("tool", False),
    "M109": ("tool", True),
    "M140": ("bed", False),
    "M190": ("bed", True),
    "M141": ("chamber", False),
    "M191": ("chamber", True),
}
#: GRBL's probing moves: they stop wherever the probe touches.
_PROBES = ("G38.2", "G38.3", "G38.4", "G38.5")
#: Moves that leave the machine where the file's coordinates cannot follow it:
#: machine coordinates (G53), a stored position (G28, G30), a probe's touch.
_LOSES_PLACE = frozenset({"G53", "G28", "G30", *_PROBES})
#: GRBL's non-modal codes whose axis words say something other than where the
#: block moves (G10 an offset, G28/G30 a stop on the way, G53 machine
#: coordinates, G92 what the position is to read).
_USES_AXIS_WORDS = frozenset({"G10", "G28", "G30", "G53", "G92", *_PROBES})
#: Mesh bed levelling a file switched on (G29 probes; a resume must never probe
#: with a part on the bed: it switches the stored mesh on instead).
LEVELLING = frozenset({"G29", "G80", "M420"})


@dataclass(slots=True)
class MachineState:
    """What the firmware holds after a run of commands (millimetres)."""

    firmware: str = "marlin"
    inches: bool = False
    absolute: bool = True
    absolute_e: bool = True
    position: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0])
    #: Which axes a move or G92 ever set: a resume moves only to those.
    known: list[bool] = field(default_factory=lambda: [False] * 4)
    #: mm/min; 0 until the file sets one.
    feedrate: float = 0.0
    tool: int = 0
    #: Targets by heater: {"tool0": 215, "bed": 60, "chamber": 0}.
    heaters: dict[str, float] = field(default_factory=dict)
    #: Fan speeds by index (0..255).
    fans: dict[str, float] = field(default_factory=dict)
    #: The last command of each replayed setting: {"M204": "M204 P1000 T1500"}.
    settings: dict[str, str] = field(default_factory=dict)
    levelling: bool = False
    #: Firmware retraction (G10) in effect: the resume's next G11 primes it.
    retracted: bool = False
    # GRBL (cnc): the work coordinate system (0 = G54), feed mode, spindle, coolant.
    coordinate_system: int = 0
    #: GRBL's modal motion (a block of axis words alone moves this way).
    motion: str = "G0"
    inverse_time: bool = False
    spindle: str = "M5"
    spindle_speed: float = 0.0
    coolant: list[str] = field(default_factory=list)
    #: The highest Z any move went to (mm, in the work coordinates without the
    #: G92 offset): a CNC resume travels above it.
    top: float = 0.0
    #: GRBL's G92 offset (X, Y, Z; mm): the file's coordinates are the work
    #: system's minus it. None for an axis whose offset the file set where the
    #: reader could not follow the machine (after a G53, G28, G30 or probing move).
    g92: list[float | None] = field(default_factory=lambda: [0.0, 0.0, 0.0])

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> MachineState:
        names = set(cls.__slots__)  # type: ignore[attr-defined]
        return cls(**{k: v for k, v in data.items() if k in names})


def words_of(text: str) -> tuple[list[str], dict[str, float]]:
    """The block's codes (`G1`, `M104`, `T1`; a GRBL block may hold several, in
    order) and its other words by letter."""
    codes: list[str] = []
    words: dict[str, float] = {}
    for place, (letter, number) in enumerate(_WORD.findall(text.upper())):
        # T leads a tool change (`T1`); after a code it is a word (M104 T1, M204 T).
        if letter in "GM" or (letter == "T" and place == 0):
            value = float(number)  # G28.1, G92.1, G38.2 are codes of their own
            whole = value.is_integer()
            codes.append(f"{letter}{int(value)}" if whole else f"{letter}{value:g}")
        else:
            words[letter] = float(number)
    return codes, words


class StateReader:
    """Feeds on commands; `state` is the machine's state after the last one."""

    def __init__(self, firmware: str = "marlin") -> None:
        self.cnc = firmware == "grbl"
        self.state = MachineState(firmware=firmware)
        self.commands = 0

    def feed(self, text: str) -> None:
        self.commands += 1
        if not text or text.startswith("$"):
            return  # GRBL settings and system commands change no modal state
        codes, words = words_of(text)
        moved = False
        for code in codes:
            if code in ("G0", "G1", "G2", "G3"):
                moved = True
                self.state.motion = code
            self._command(code, words, text)
        if self.cnc and _USES_AXIS_WORDS.intersection(codes):
            # Their axis words are not the block's move: G53 moves in machine
            # coordinates, G28 and G30 to a position stored in the machine.
            if "F" in words and words["F"] > 0:
                self.state.feedrate = self._scale(words["F"])
            self._lose(_LOSES_PLACE.intersection(codes), words)
        elif moved or (self.cnc and not codes and words):
            self._move(words)  # a GRBL block of axis words keeps the last motion
        elif self.cnc and "F" in words:
            self.state.feedrate = self._scale(words["F"])

    def _lose(self, codes: set[str], words: dict[str, float]) -> None:
        """After a move the file's coordinates cannot follow (`_LOSES_PLACE`),
        the axes it moved are where the machine is, not anywhere the reader knows."""
        if not codes:
            return
        named = [axis for axis in range(3) if _AXES[axis] in words]
        if codes & {"G28", "G30"} and not named:
            named = [0, 1, 2]  # without axis words, every axis goes there
        for axis in named:
            self.state.known[axis] = False

    def _command(self, code: str, words: dict[str, float], text: str) -> None:
        state = self.state
        if code == "G90":
            state.absolute = True
            if not self.cnc:
                state.absolute_e = True
        elif code == "G91":
            state.absolute = False
            if not self.cnc:
                state.absolute_e = False
        elif code == "M82":
            state.absolute_e = True
        elif code == "M83":
            state.absolute_e = False
        elif code in ("G20", "G21"):
            state.inches = code == "G20"
        elif code == "G92":
            self._set_position(words)
        elif code == "G28" and not self.cnc:
            self._home(words)
        elif code == "G10" and "P" in words and "L" not in words and not self.cnc:
            # RepRapFirmware's tool temperatures: G10 P<tool> S<active> R<standby>
            # (no retraction; a G10 P without S or R sets offsets).
            if "S" in words:
                state.heaters[f"tool{int(words['P'])}"] = words["S"]
        elif code == "M568" and not self.cnc:  # RepRapFirmware 3.3+: the same
            if "S" in words:
                state.heaters[f"tool{int(words.get('P', state.tool))}"] = words["S"]
        elif code in ("G10", "G11") and not self.cnc:
            state.retracted = code == "G10" and "L" not in words
        elif code[0] == "T":
            state.tool = int(code[1:])
        elif code in HEATERS and not self.cnc:
            self._heater(code, words)
        elif code in ("M106", "M107") and not self.cnc:
            index = str(int(words.get("P", 0)))
            state.fans[index] = words.get("S", 255.0) if code == "M106" else 0.0
        elif code in REPLAYED and not self.cnc:
            self._setting(code, words, text)
        elif code in LEVELLING and not self.cnc:
            state.levelling = code != "M420" or words.get("S", 1.0) != 0
        elif self.cnc:
            self._cnc_mode(code, words)

    def _setting(self, code: str, words: dict[str, float], text: str) -> None:
        """Keep *text* for replay, with the code's earlier commands for the same
        tool or extruder that it wholly covers dropped (`M204 P800` then `M204
        T1500` both stay; `M221 T0 S90` and `M221 T1 S110` both stay; a later
        `M204 P900 T1000` replaces both M204s). The last set is replayed last."""
        selector = SELECTORS.get(code, "")
        which = f"{selector}{int(words[selector])}" if selector in words else ""
        letters = "".join(sorted(set(words) - {selector}))
        settings = self.state.settings
        for key in list(settings):
            old_code, _, rest = key.partition(" ")
            old_which, _, old_letters = rest.partition(" ")
            covered = set(old_letters) <= set(letters)
            if old_code == code and old_which == which and covered:
                del settings[key]
        settings[f"{code} {which} {letters}"] = text

    def _scale(self, value: float) -> float:
        return value * INCH if self.state.inches else value

    def _move(self, words: dict[str, float]) -> None:
        state = self.state
        if "F" in words and words["F"] > 0:
            state.feedrate = self._scale(words["F"])
        for axis, letter in enumerate(_AXES):
            if letter not in words or (self.cnc and letter == "E"):
                continue
            value = self._scale(words[letter])
            absolute = state.absolute_e if letter == "E" else state.absolute
            if absolute:
                state.position[axis] = value
            else:
                state.position[axis] += value
            state.known[axis] = True
        offset = state.g92[2] if self.cnc else 0.0
        if "Z" in words and offset is not None:
            state.top = max(state.top, state.position[2] + offset)
        if self.cnc and "S" in words:
            state.spindle_speed = words["S"]

    def _set_position(self, words: dict[str, float]) -> None:
        state = self.state
        given = [letter for letter in _AXES if letter in words]
        if not given and not self.cnc:
            given = list(_AXES)
            words = dict.fromkeys(_AXES, 0.0)
        for letter in given:
            axis = _AXES.index(letter)
            value = self._scale(words[letter])
            if self.cnc and axis < 3:
                # The offset that makes the work position read *value* here.
                offset = state.g92[axis]
                state.g92[axis] = (
                    state.position[axis] + offset - value
                    if state.known[axis] and offset is not None
                    else None
                )
            state.position[axis] = value
            state.known[axis] = True

    def _clear_g92(self) -> None:
        """G92.1: the work coordinates without the G92 offset again."""
        state = self.state
        for axis, offset in enumerate(state.g92):
            if offset is None:
                state.known[axis] = False
            else:
                state.position[axis] += offset
        state.g92 = [0.0, 0.0, 0.0]

    def _set_work_offset(self, words: dict[str, float]) -> None:
        """G10 L2 (the offset itself) or L20 (the offset that makes the position
        read the words) of a work coordinate system: P0 is the one in use."""
        state = self.state
        system = int(words.get("P", 0)) - 1
        if system not in (-1, state.coordinate_system):
            return  # another system's: nothing moves in this one
        for axis in range(3):
            if _AXES[axis] in words:
                if words.get("L") == 20:
                    state.position[axis] = self._scale(words[_AXES[axis]])
                    state.known[axis] = True
                else:
                    state.known[axis] = False

    def _home(self, words: dict[str, float]) -> None:
        state = self.state
        axes = [a for a in range(3) if _AXES[a] in words] or [0, 1, 2]
        for axis in axes:
            state.position[axis] = 0.0
            state.known[axis] = True

    def _heater(self, code: str, words: dict[str, float]) -> None:
        kind, _ = HEATERS[code]
        target = words.get("S", words.get("R"))
        if target is None:
            return
        name = kind
        if kind == "tool":
            name = f"tool{int(words.get('T', self.state.tool))}"
        self.state.heaters[name] = target

    def _cnc_mode(self, code: str, words: dict[str, float]) -> None:
        state = self.state
        if code in ("G54", "G55", "G56", "G57", "G58", "G59"):
            system = int(code[1:]) - 54
            if system != state.coordinate_system:
                state.known[:3] = [False] * 3  # the same spot, other coordinates
            state.coordinate_system = system
        elif code == "G92.1":
            self._clear_g92()
        elif code == "G10" and words.get("L") in (2, 20):
            self._set_work_offset(words)
        elif code in ("G93", "G94"):
            state.inverse_time = code == "G93"
        elif code in ("M3", "M4", "M5"):
            state.spindle = code
            if "S" in words:
                state.spindle_speed = words["S"]
        elif code in ("M7", "M8"):
            if code not in state.coolant:
                state.coolant.append(code)
        elif code == "M9":
            state.coolant = []


def offsets_lost(state: MachineState) -> list[str]:
    """CNC: the axes whose G92 offset a preamble cannot set again at the state's
    line: an offset set where the reader had lost the axis, or one on X or Y with
    the axis unplaced there (the preamble sets it over the point; Z it places)."""
    return [
        letter
        for letter, offset, known in zip("XYZ", state.g92, state.known, strict=False)
        if offset is None or (offset and not known and letter != "Z")
    ]
