"""Events the firmware protocols hand to the worker: small value objects.

Frozen, except the three every line brings (Sent, Received, Ack): a frozen
dataclass sets each field through object.__setattr__, which made making them
three times as dear. Nothing changes an event once made.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

__all__ = [
    "Ack",
    "ActionCommand",
    "Alarm",
    "Busy",
    "Capability",
    "CommandFailed",
    "Event",
    "FirmwareError",
    "FirmwareHalted",
    "FirmwareInfo",
    "FirmwareMessage",
    "FirmwareReset",
    "LineKind",
    "LinkFailed",
    "Received",
    "ResendServed",
    "Sent",
    "StatusReport",
    "TemperatureReport",
]


class LineKind(enum.IntFlag):
    """Repetier's response-log filter bits: a client hides a kind by setting its bit."""

    #: A command we sent to the firmware.
    COMMAND = 1
    #: Acknowledgements and routine reports: ok, wait, temperatures, status reports.
    ACK = 2
    #: Every other firmware line: echo:, messages, capability lines.
    RESPONSE = 4
    #: Lines nobody may hide: errors, alarms, resets, halts, host actions.
    IMPORTANT = 8


class Event:
    """Base class of protocol events."""

    __slots__ = ()


@dataclass(slots=True)
class Sent(Event):
    """A line went to the wire (without the newline), as the firmware will see it."""

    text: str
    #: The line number it carries, or None for an unnumbered line.
    line_number: int | None = None
    #: True when this is a retransmission asked for by a resend request or a timeout.
    resend: bool = False


@dataclass(slots=True)
class Received(Event):
    """A whole line came from the firmware; emitted for every line, before its meaning."""

    text: str
    kind: LineKind


@dataclass(slots=True)
class Ack(Event):
    """The firmware accepted the command sent with *tag* (Marlin `ok`, GRBL `ok`)."""

    tag: object


@dataclass(frozen=True, slots=True)
class CommandFailed(Event):
    """The firmware refused the command sent with *tag* (GRBL `error:N`).

    It still counts as answered: the window moves on. The worker decides whether the
    stream may carry on (it does not, mid-job).
    """

    tag: object
    message: str
    code: int | None = None


@dataclass(frozen=True, slots=True)
class ResendServed(Event):
    """A resend request for *line_number* was accepted and the lines are going again."""

    line_number: int
    message: str = ""


@dataclass(frozen=True, slots=True)
class Busy(Event):
    """`echo:busy: processing` and friends: the firmware is alive, the ack will be late."""

    message: str


@dataclass(frozen=True, slots=True)
class TemperatureReport(Event):
    """Current and target temperatures, keyed by sensor: "T0", "T1", "B", "C"."""

    readings: dict[str, tuple[float, float | None]]


@dataclass(frozen=True, slots=True)
class FirmwareInfo(Event):
    """M115's first line (`FIRMWARE_NAME:...`) or GRBL's `[VER:...]`."""

    name: str
    fields: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Capability(Event):
    """An M115 `Cap:NAME:0|1` line."""

    name: str
    enabled: bool


@dataclass(frozen=True, slots=True)
class ActionCommand(Event):
    """A `//action:<action> <argument>` host command from the firmware."""

    action: str
    argument: str = ""


@dataclass(frozen=True, slots=True)
class FirmwareReset(Event):
    """The firmware (re)started: Marlin `start`, GRBL's welcome banner.

    Everything in flight is gone; line numbers are reset. Mid-job this stops the job.
    """

    banner: str


@dataclass(frozen=True, slots=True)
class FirmwareHalted(Event):
    """The firmware stopped itself (kill(), thermal runaway, M112, `Printer halted`)."""

    message: str


@dataclass(frozen=True, slots=True)
class FirmwareError(Event):
    """An `Error:` line that is neither part of the resend flow nor a halt.

    Examples: `Error:Probing failed`, `Error:Printer halted` is a halt instead. Mid-job
    the worker stops the stream with this message.
    """

    message: str


@dataclass(frozen=True, slots=True)
class Alarm(Event):
    """GRBL `ALARM:N`: motion is locked until `$X` or `$H`."""

    code: int
    message: str


@dataclass(frozen=True, slots=True)
class StatusReport(Event):
    """GRBL `<Idle|MPos:...|FS:...>`: machine state and its fields."""

    state: str
    fields: dict[str, str]


@dataclass(frozen=True, slots=True)
class FirmwareMessage(Event):
    """An informational line: Marlin `echo:`, GRBL `[MSG:...]`, unknown text."""

    text: str


@dataclass(frozen=True, slots=True)
class LinkFailed(Event):
    """The link cannot go on safely (ack timeout, resend limit): stop the stream, say why."""

    message: str
