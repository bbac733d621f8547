"""Events only GRBL (and grblHAL) sends: build options, check mode, unlock, program end."""

from __future__ import annotations

from dataclasses import dataclass, field

from printers.protocol.events import Event

__all__ = ["BuildOptions", "CheckMode", "Locked", "ProgramEnd", "Unlocked"]


@dataclass(frozen=True, slots=True)
class BuildOptions(Event):
    """`[OPT:VL,15,128]` from `$I`: compile-time options and buffer sizes.

    grbl 1.1 writes `[OPT:<letters>,<planner blocks>,<RX buffer bytes>]`; grblHAL
    appends the number of axes (and more). None where the report has no number.
    """

    letters: str
    planner_blocks: int | None
    rx_buffer: int | None
    #: Every field as written, for showing: {"OPT": "VL,15,128"}.
    fields: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class CheckMode(Event):
    """`$C` toggled: `[MSG:Enabled]` (lines are parsed, nothing moves) or `[MSG:Disabled]`."""

    enabled: bool


@dataclass(frozen=True, slots=True)
class Unlocked(Event):
    """`[MSG:Caution: Unlocked]`: `$X` cleared an alarm lock."""

    text: str


@dataclass(frozen=True, slots=True)
class Locked(Event):
    """`[MSG:'$H'|'$X' to unlock]`: GRBL started (or reset) in its Alarm lock."""

    text: str


@dataclass(frozen=True, slots=True)
class ProgramEnd(Event):
    """`[MSG:Pgm End]`: M2/M30 ran. The job still ends with its last ack, not here."""
