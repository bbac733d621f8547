"""Sans-IO firmware protocols: bytes and `now` in, bytes and events out (h11 style).

Nothing in this package imports Django or pyserial, reads a clock, sleeps or logs.
"""

from __future__ import annotations

from printers.protocol.checksum import checksum, clean_line, format_line
from printers.protocol.errors import (
    CommandRejected,
    LocalProtocolError,
    ProtocolError,
    RemoteProtocolError,
)
from printers.protocol.events import (
    Ack,
    ActionCommand,
    Alarm,
    Busy,
    Capability,
    CommandFailed,
    Event,
    FirmwareError,
    FirmwareHalted,
    FirmwareInfo,
    FirmwareMessage,
    FirmwareReset,
    LineKind,
    LinkFailed,
    Received,
    ResendServed,
    Sent,
    StatusReport,
    TemperatureReport,
)
from printers.protocol.grbl import GrblProtocol
from printers.protocol.link import LinkProtocol
from printers.protocol.marlin import MarlinProtocol

__all__ = [
    "Ack",
    "ActionCommand",
    "Alarm",
    "Busy",
    "Capability",
    "CommandFailed",
    "CommandRejected",
    "Event",
    "FirmwareError",
    "FirmwareHalted",
    "FirmwareInfo",
    "FirmwareMessage",
    "FirmwareReset",
    "GrblProtocol",
    "LineKind",
    "LinkFailed",
    "LinkProtocol",
    "LocalProtocolError",
    "MarlinProtocol",
    "ProtocolError",
    "Received",
    "RemoteProtocolError",
    "ResendServed",
    "Sent",
    "StatusReport",
    "TemperatureReport",
    "checksum",
    "clean_line",
    "format_line",
]
