"""Helpers of GrblProtocol's tests: a protocol that does not poll, its events, and
the lines that write GRBL's EEPROM."""

from __future__ import annotations

from printers.protocol.events import Event, Received, Sent
from printers.protocol.grbl import GrblProtocol

BANNER = b"Grbl 1.1h ['$' for help]\r\n"
EEPROM_WRITES = [
    "$100=250.000",
    "$N0=G20 G54",
    "$N1=",
    "$I=shop router",
    "$RST=$",
    "$rst=*",
    "G10 L2 P1 X0 Y0",
    "G10L20P1X0",
    "G28.1",
    "G30.1",
]
PLAIN_LINES = ["$$", "$H", "$X", "$#", "$N", "$J=G91 X1 F100", "G28", "G30", "G10 L200"]


def make(**options: object) -> GrblProtocol:
    """A protocol that does not poll, so tests see only the bytes they cause."""
    options.setdefault("status_interval", None)
    return GrblProtocol(**options)  # type: ignore[arg-type]


def drain(protocol: GrblProtocol) -> list[Event]:
    events = []
    while (event := protocol.next_event()) is not None:
        events.append(event)
    return events


def meanings(protocol: GrblProtocol) -> list[Event]:
    """Events without the Received/Sent log lines."""
    return [e for e in drain(protocol) if not isinstance(e, Received | Sent)]


def fill(protocol: GrblProtocol, text: str, now: float = 0.0) -> int:
    """Send *text* until the window is full; returns how many went."""
    count = 0
    while protocol.can_send(text):
        protocol.send(text, now, tag=count)
        count += 1
    return count


def as_wire(text: str) -> str:
    """What compact mode should make of *text*, worked out independently."""
    text = text.strip()
    if text.startswith("$") or "(" in text:
        return text
    return text.replace(" ", "")
