"""What the stream host tells the worker (`StreamHost.next_event`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from printers.streaming.streams import Line, Stream

__all__ = [
    "CommandAnswered",
    "EspCommand",
    "HostEvent",
    "StreamEnded",
    "StreamPaused",
    "StreamResumed",
    "StreamStarted",
]


@dataclass(frozen=True, slots=True)
class StreamStarted:
    stream: Stream


@dataclass(frozen=True, slots=True)
class StreamPaused:
    stream: Stream


@dataclass(frozen=True, slots=True)
class StreamResumed:
    stream: Stream


@dataclass(frozen=True, slots=True)
class StreamEnded:
    """A stream left its queue; `stream.outcome` is completed, aborted or failed."""

    stream: Stream


@dataclass(frozen=True, slots=True)
class EspCommand:
    """An `[ESPxxx]` line was read from a stream: the worker answers it to the origin."""

    stream: Stream
    text: str


@dataclass(frozen=True, slots=True)
class CommandAnswered:
    """A script line got its ack (ok) or was refused (message)."""

    stream: Stream
    line: Line
    ok: bool
    message: str = ""


HostEvent = (
    StreamStarted
    | StreamPaused
    | StreamResumed
    | StreamEnded
    | EspCommand
    | CommandAnswered
)
