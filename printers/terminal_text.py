"""The raw TCP terminal's text in and out: a client's lines, held to a limit, and
printer output with its control characters removed (printers/terminal.py)."""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import asyncio

#: Longest line a client may send (bytes); longer ones are refused and discarded.
MAX_LINE = 4096
#: How much is read from a client at a time (bytes).
READ_BYTES = 65536
#: Control characters never written to a client: C0 but tab, DEL, C1.
_CONTROL = re.compile(r"[\x00-\x08\x0a-\x1f\x7f-\x9f]")


def printable(text: str) -> str:
    """*text* without control characters (ESC sequences lose their ESC), tabs kept."""
    return _CONTROL.sub("", text)


class TooLong:
    """What `LineReader.next` returns for a line over its limit."""


TOO_LONG = TooLong()


class LineReader:
    """A client's lines, never holding more than *limit* bytes of one.

    A line over the limit is discarded up to its newline (what arrives of it is
    dropped as it comes) and reported once as TOO_LONG.
    """

    def __init__(self, reader: asyncio.StreamReader, limit: int = MAX_LINE) -> None:
        self.reader = reader
        self.limit = limit
        self.buffer = bytearray()
        self.discarding = False

    async def next(self) -> bytes | TooLong | None:
        """The next line (with its newline), TOO_LONG, or None at end of input."""
        while True:
            end = self.buffer.find(b"\n")
            if end >= 0:
                line = bytes(self.buffer[: end + 1])
                del self.buffer[: end + 1]
                if self.discarding or len(line) > self.limit + 1:
                    self.discarding = False
                    return TOO_LONG
                return line
            if len(self.buffer) > self.limit:
                self.buffer.clear()
                self.discarding = True
            data = await self.reader.read(READ_BYTES)
            if not data:
                return None
            self.buffer += data
