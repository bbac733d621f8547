"""A command line as GRBL will see it: checked, compacted, sized, and the settings' limits."""

from __future__ import annotations

from dataclasses import dataclass

from printers.protocol.errors import CommandRejected
from printers.protocol.grbl_codes import line_traits

__all__ = ["Line", "check_settings", "prepare_line"]


@dataclass(frozen=True, slots=True)
class Line:
    """A command line on its way to GRBL or waiting for its answer."""

    #: As written to the wire, without the newline.
    text: str
    tag: object
    #: An EEPROM write: it must be alone in GRBL's buffer (send-response).
    sync: bool
    #: Seconds of G4 dwell: GRBL sits Idle that long before answering.
    dwell: float

    @property
    def size(self) -> int:
        return len(self.text) + 1


def prepare_line(
    text: str, tag: object, max_line_length: int, *, compact: bool
) -> Line:
    """*text* ready for the wire; CommandRejected when GRBL cannot take it."""
    wire = _wire_text(text, max_line_length, compact=compact)
    return Line(wire, tag, *line_traits(wire))


def _wire_text(text: str, max_line_length: int, *, compact: bool) -> str:
    if not text.strip():
        raise CommandRejected("empty command: there is nothing to send")
    if (
        text.isascii()
        and text.isprintable()
        and "?" not in text
        and "!" not in text
        and "~" not in text
    ):
        return _checked_length(
            _compacted(text.strip(), compact=compact), max_line_length
        )
    bad = next((char for char in text if not " " <= char <= "~"), None)
    if bad is not None:
        raise CommandRejected(
            f"{text!r} holds {bad!r}: GRBL takes printable ASCII only"
        )
    realtime = next((char for char in text if char in "?!~"), None)
    if realtime is not None:
        raise CommandRejected(
            f"{text!r} holds {realtime!r}, a GRBL realtime command that would act "
            "at once; send it alone with send_emergency()"
        )
    return _checked_length(_compacted(text.strip(), compact=compact), max_line_length)


def _checked_length(wire: str, max_line_length: int) -> str:
    if len(wire) > max_line_length:
        raise CommandRejected(
            f"'{wire}' is {len(wire)} characters long; GRBL takes at most "
            f"{max_line_length} per line"
        )
    return wire


def _compacted(text: str, *, compact: bool) -> str:
    # Spaces are free for GRBL to ignore but cost buffer bytes. `$` lines (stored
    # startup lines, build info), comments and quoted text keep theirs.
    if not compact or text.startswith("$") or "(" in text or '"' in text or "'" in text:
        return text
    return text.replace(" ", "")


def check_settings(
    rx_buffer: int,
    max_line_length: int,
    ack_timeout: float,
    status_interval: float | None,
) -> None:
    """ValueError unless the settings describe a link that can carry a line."""
    if max_line_length < 1:
        raise ValueError(f"max_line_length must be at least 1, not {max_line_length}")
    if rx_buffer < max_line_length + 1:
        raise ValueError(
            f"rx_buffer ({rx_buffer}) must hold the longest line and its newline "
            f"({max_line_length + 1} bytes)"
        )
    if not ack_timeout > 0:
        raise ValueError(f"ack_timeout must be positive, not {ack_timeout}")
    if status_interval is not None and not status_interval > 0:
        raise ValueError(
            f"status_interval must be positive or None, not {status_interval}"
        )
