"""ESP3D's G-code streaming, sans-IO: stream types, the three queues, command states."""

from __future__ import annotations

from printers.streaming.host import StreamHost
from printers.streaming.printer_side import PrinterSide
from printers.streaming.streams import (
    CommandState,
    Line,
    QueueState,
    Stream,
    StreamType,
    lines_from_text,
)

__all__ = [
    "CommandState",
    "Line",
    "PrinterSide",
    "QueueState",
    "Stream",
    "StreamHost",
    "StreamType",
    "lines_from_text",
]
