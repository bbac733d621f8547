"""How the simulated Marlin reads lines: the emergency parser, line checks, errors.

A mixin of MarlinFirmware (queue.cpp's get_serial_commands and gcode_line_error):
bytes from the RX ring become checked commands in the queue, or a line error in
the firmware's dialect.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from printers.protocol.checksum import parse_framed_line

if TYPE_CHECKING:
    from printers.simulator.marlin import MarlinFirmware

__all__ = ["CODE", "MAX_LINE", "Command", "LineInput"]

#: MAX_CMD_SIZE - 1: the rest of a longer line is skipped.
MAX_LINE = 95
#: The line the emergency parser reacts to (it sees bytes before the ring does).
_EMERGENCY = re.compile(
    rb"(?m)^[ \t]*(?:N-?\d+[ \t]*)?M(108|112|410|876)(?![0-9])([^\n]*)\n"
)
CODE = re.compile(r"([GMTgmt])\s*(\d+)")


class Command:
    """A command in the queue; one read from the SD card sends no ok (no port)."""

    __slots__ = ("from_card", "number", "text")

    def __init__(
        self, text: str, number: int | None, *, from_card: bool = False
    ) -> None:
        self.text = text
        self.number = number
        self.from_card = from_card


class LineInput:
    """Reading the serial side: emergency parser, line numbers and checksums."""

    def _scan_emergency(self: MarlinFirmware, data: bytes, now: float) -> None:
        """EMERGENCY_PARSER: act on M108/M112/M410 as their line end arrives."""
        chunk = self._ep_tail + data.replace(b"\r", b"\n")
        cut = chunk.rfind(b"\n") + 1
        self._ep_tail = chunk[cut:][-64:]
        if b"M" not in chunk[:cut]:
            return
        for match in _EMERGENCY.finditer(chunk, 0, cut):
            code = match[1].decode()
            if self.pause.on_emergency(code, match[2].decode("latin-1")):
                self._poked = True  # M108 or M876 S0 continues a parked M600
            if code == "876":
                continue
            self._emergency(code, now)
            if self.killed:
                return

    def _emergency(self: MarlinFirmware, code: str, now: float) -> None:
        if code == "112":
            # Recorded here: a kill() stops everything, so it never reaches the queue.
            if self.on_execute is not None:
                self.on_execute("M112")
            self.halt(now)
        elif code == "108":
            self.machine.cancel_wait = True
            self._poked = True
        else:
            self.machine.quickstop(now)
            self._poked = True

    def _on_line(self: MarlinFirmware, raw: bytes, now: float) -> None:
        if self.faults is not None:
            raw = self.faults.corrupt_line(raw)
        line = raw.decode("latin-1")
        if ";" in line:
            line = line[: line.index(";")]
        line = line[:MAX_LINE].strip()
        if not line:
            return
        if self.echo_lines:
            self._print(f"echo:{line}" if self.echo_lines == "echo" else line)
        number = None
        if line[0] != "N" and "*" in line and self.dialect.no_line_number:
            self._line_error(self.dialect.no_line_number, None)
            return
        if line[0] == "N":
            checked = self._check_line(line)
            if checked is None:
                return
            number, line = checked
        if not self.emergency_parser and line[:1] in "Mm":
            self._early_emergency(line, now)
            if self.killed:
                return
        self._queue.append(Command(line, number))
        self._execute(now)

    def _check_line(self: MarlinFirmware, line: str) -> tuple[int, str] | None:
        """Marlin's order: line number, then checksum. Returns (number, command)."""
        number, command, good = parse_framed_line(line)
        dialect = self.dialect
        expected = number
        if "M110" in line:
            second = re.search(r"N(-?\d+)", line[4:])
            expected = int(second[1]) if second else number
        elif dialect.sequence and (number or 0) != self._last_n + 1:
            if (
                dialect.skip_duplicates
                and number is not None
                and number <= self._last_n
            ):
                self._print(f"skip {number}", "ok")
            else:
                self._line_error(dialect.line_number, number)
            return None
        if not good:
            star = "*" in line
            self._line_error(dialect.checksum if star else dialect.no_checksum, number)
            return None
        self._last_n = expected if expected is not None else 0
        return (number if number is not None else 0), command

    def _line_error(self: MarlinFirmware, message: str | None, got: int | None) -> None:
        """gcode_line_error: report, flush the RX ring, ask for the line again, ok.

        A dialect without a message (RepRapFirmware) drops the line silently.
        """
        if message is None:
            return
        self._reader.flush()
        self._print(*self.dialect.rejection(message, self._last_n, got, self._ok_order))

    def _early_emergency(self: MarlinFirmware, line: str, now: float) -> None:
        """Without the parser, queue.cpp acts on these when the line is read."""
        code = CODE.match(line)
        if code is not None and code[2] in ("108", "112", "410"):
            self._emergency(code[2], now)
