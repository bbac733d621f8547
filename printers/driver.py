"""Drivers (MeerK40t's word): a firmware protocol bound to where its bytes go.

`protocol_for(config)` builds the sans-IO protocol a printer's settings ask for; the
worker binds it to a SerialTransport. `FileDriver` binds it to a file instead, so
exporting a job writes exactly the bytes a print would send, line numbers and
checksums included (MeerK40t's "save G-code = run the job on a file driver").
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, BinaryIO

from printers.protocol.events import Sent
from printers.protocol.grbl import GrblProtocol
from printers.protocol.marlin import MarlinProtocol

if TYPE_CHECKING:
    from collections.abc import Iterable

    from printers.models import Printer
    from printers.protocol.link import LinkProtocol

#: Longest command line each firmware takes when the printer does not say.
DEFAULT_LINE_LIMIT = {"marlin": 95, "reprap": 250, "repetier": 95, "grbl": 79}


@dataclass(frozen=True, slots=True)
class LinkConfig:
    """The printer settings a protocol needs, detached from the database row."""

    firmware: str = "marlin"
    baud: int = 115200
    checksums: str = "printing"
    flow: str = "auto"
    rx_buffer: int = 127
    bufsize: int = 4
    max_line_length: int = 0
    ack_timeout: float = 10.0
    busy_timeout: float = 30.0
    max_resends: int = 10
    status_interval: float = 0.2

    @classmethod
    def from_printer(cls, printer: Printer) -> LinkConfig:
        return cls(
            firmware=printer.firmware,
            baud=printer.baud,
            checksums=printer.checksums,
            flow=printer.flow,
            rx_buffer=printer.rx_buffer,
            bufsize=printer.bufsize,
            max_line_length=printer.max_line_length,
            ack_timeout=printer.ack_timeout,
            busy_timeout=printer.busy_timeout,
            max_resends=printer.max_resends,
            status_interval=printer.status_interval,
        )

    @property
    def line_limit(self) -> int:
        return self.max_line_length or DEFAULT_LINE_LIMIT.get(self.firmware, 95)

    @property
    def command_limit(self) -> int:
        """Longest command text that still fits once framed (`N<n> ` and `*<cs>`)."""
        if self.firmware == "grbl":
            return self.line_limit
        return self.line_limit - len("N10000000 *255")


def protocol_for(config: LinkConfig) -> LinkProtocol:
    """The protocol a printer's firmware and flow settings call for."""
    if config.firmware == "grbl":
        return GrblProtocol(
            rx_buffer=config.rx_buffer,
            max_line_length=config.line_limit,
            ack_timeout=config.ack_timeout,
            status_interval=config.status_interval or None,
        )
    return MarlinProtocol(
        checksums=config.checksums,
        flow=config.flow,
        rx_buffer=config.rx_buffer,
        bufsize=config.bufsize,
        max_line_length=config.line_limit,
        ack_timeout=config.ack_timeout,
        busy_timeout=config.busy_timeout,
        max_resends=config.max_resends,
        baud=config.baud,
    )


class FileDriver:
    """Runs commands through a protocol as a print would, writing the wire bytes to a file.

    Every line is acknowledged at once, as a perfect firmware would, so the output
    is the exact byte sequence of an error-free print.
    """

    def __init__(self, config: LinkConfig, out: BinaryIO) -> None:
        # No status polls: a file has no one to answer them.
        self.protocol = protocol_for(replace(config, status_interval=0))
        self.protocol.printing = True
        if isinstance(self.protocol, GrblProtocol):
            self.protocol.wait_for_idle = False  # a file never moves
        self.out = out
        self.lines = 0

    def run(self, commands: Iterable[str]) -> int:
        """Write *commands* as they would go to the printer; returns lines written."""
        now = 0.0
        if isinstance(self.protocol, MarlinProtocol):
            self.protocol.reset_line_numbers(now)
            self._drain(now)
        for text in commands:
            self.protocol.send(text, now, tag=None)
            self._drain(now)
        return self.lines

    def _drain(self, now: float) -> None:
        data = self.protocol.data_to_send()
        self.out.write(data)
        for event in _events(self.protocol):
            if isinstance(event, Sent):
                self.lines += 1
        if data and self.protocol.in_flight:
            self.protocol.receive_data(b"ok\n" * self.protocol.in_flight, now)
            _events(self.protocol)


def _events(protocol: LinkProtocol) -> list[object]:
    events = []
    while (event := protocol.next_event()) is not None:
        events.append(event)
    return events
