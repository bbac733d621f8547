"""Streams: the spooler's jobs (MeerK40t), typed as ESP3D types them, and their command states.

Command states of a stream and the moves allowed between them (anything else raises
LocalProtocolError, as h11's tables do):

    state                  next states
    ---------------------  ---------------------------------------------------
    START                  READY_TO_READ_CURSOR
    READY_TO_READ_CURSOR   READ_CURSOR, WAIT_FOR_ACK (end of file), PAUSE, ABORT,
                           ERROR, END
    READ_CURSOR            SEND_GCODE_COMMAND, SEND_ESP_COMMAND
    SEND_GCODE_COMMAND     READY_TO_READ_CURSOR, WAIT_FOR_ACK (no room), ERROR
    SEND_ESP_COMMAND       READY_TO_READ_CURSOR
    WAIT_FOR_ACK           READY_TO_READ_CURSOR, RESEND_GCODE_COMMAND, PAUSE,
                           ABORT, ERROR, END
    RESEND_GCODE_COMMAND   WAIT_FOR_ACK, READY_TO_READ_CURSOR, ERROR, PAUSE, ABORT
    PAUSE                  PAUSED
    PAUSED                 RESUME, ABORT, ERROR
    RESUME                 READY_TO_READ_CURSOR
    ABORT                  END
    ERROR                  END
    END                    (removed from its queue)

SEND_GCODE_COMMAND offers the line to the protocol, which takes it or says there is no
room (`LinkProtocol.offer`). WAIT_FOR_ACK means "the window is full" (or, at the end of
the file, "waiting for the last acks", the closing sync's too): with more than one command in flight, ESP3D's
ping-pong wait becomes a wait for room. A pause or abort asked for while waiting takes
effect at once, since no command is half-sent there.
"""

from __future__ import annotations

import enum
import itertools
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from printers.protocol.errors import LocalProtocolError

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator

    from printers.streaming.printer_side import PrinterSide


class StreamType(enum.Enum):
    """ESP3D's stream types; `/sd/` and `/fs/` both name the printer's job storage."""

    UNKNOWN = "unknown"
    SINGLE_COMMAND = "single command"
    MULTIPLE_COMMANDS = "multiple commands"
    FS_FILE_STREAM = "fs file stream"
    FS_FILE_SCRIPT = "fs file script"
    SD_FILE_STREAM = "sd file stream"
    SD_FILE_SCRIPT = "sd file script"
    INVALID = "invalid"

    @property
    def is_stream(self) -> bool:
        """Goes to the stream queue: interruptible between commands, [ESP701] controls it."""
        return self in (StreamType.FS_FILE_STREAM, StreamType.SD_FILE_STREAM)

    @property
    def is_file(self) -> bool:
        """Its lines come from a stored file (not a client's own commands)."""
        return self.is_stream or self in (
            StreamType.FS_FILE_SCRIPT,
            StreamType.SD_FILE_SCRIPT,
        )

    @property
    def is_script(self) -> bool:
        """Goes to the script queue: runs to its end, ahead of the stream queue."""
        return self in (
            StreamType.SINGLE_COMMAND,
            StreamType.MULTIPLE_COMMANDS,
            StreamType.FS_FILE_SCRIPT,
            StreamType.SD_FILE_SCRIPT,
        )


class QueueState(enum.Enum):
    """State of the stream queue (ESP3D); a failed stream is removed, so no ERROR here."""

    #: The stream queue is empty (the script queue may not be).
    IDLE = "idle"
    #: A stream is being processed, possibly on hold while scripts run.
    PROCESSING = "processing"
    #: The active stream is paused.
    PAUSED = "paused"


class CommandState(enum.Enum):
    """Where the active stream is in handling its current command (ESP3D's names)."""

    # Members are compared by identity: hashing them so too keeps the table
    # lookups of every step (several a line) off Enum's Python-level __hash__.
    __hash__ = object.__hash__

    UNDEFINED = "undefined"
    START = "start"
    READY_TO_READ_CURSOR = "ready to read cursor"
    READ_CURSOR = "read cursor"
    SEND_GCODE_COMMAND = "send gcode command"
    SEND_ESP_COMMAND = "send esp command"
    WAIT_FOR_ACK = "wait for ack"
    RESEND_GCODE_COMMAND = "resend gcode command"
    PAUSE = "pause"
    PAUSED = "paused"
    RESUME = "resume"
    ABORT = "abort"
    END = "end"
    ERROR = "error"


_S = CommandState
TRANSITIONS: dict[CommandState, frozenset[CommandState]] = {
    _S.START: frozenset({_S.READY_TO_READ_CURSOR}),
    _S.READY_TO_READ_CURSOR: frozenset(
        {_S.READ_CURSOR, _S.WAIT_FOR_ACK, _S.PAUSE, _S.ABORT, _S.ERROR, _S.END}
    ),
    _S.READ_CURSOR: frozenset({_S.SEND_GCODE_COMMAND, _S.SEND_ESP_COMMAND}),
    _S.SEND_GCODE_COMMAND: frozenset(
        {_S.READY_TO_READ_CURSOR, _S.WAIT_FOR_ACK, _S.ERROR}
    ),
    _S.SEND_ESP_COMMAND: frozenset({_S.READY_TO_READ_CURSOR}),
    _S.WAIT_FOR_ACK: frozenset(
        {
            _S.READY_TO_READ_CURSOR,
            _S.RESEND_GCODE_COMMAND,
            _S.PAUSE,
            _S.ABORT,
            _S.ERROR,
            _S.END,
        }
    ),
    _S.RESEND_GCODE_COMMAND: frozenset(
        {_S.WAIT_FOR_ACK, _S.READY_TO_READ_CURSOR, _S.ERROR, _S.PAUSE, _S.ABORT}
    ),
    _S.PAUSE: frozenset({_S.PAUSED}),
    _S.PAUSED: frozenset({_S.RESUME, _S.ABORT, _S.ERROR}),
    _S.RESUME: frozenset({_S.READY_TO_READ_CURSOR}),
    _S.ABORT: frozenset({_S.END}),
    _S.ERROR: frozenset({_S.END}),
    _S.END: frozenset(),
}


#: Requests (pause, resume, abort) and the state each one moves a stream to; a
#: request is taken only in the states REQUESTS_FROM allows it from.
REQUEST_MOVES = {"pause": _S.PAUSE, "abort": _S.ABORT, "resume": _S.RESUME}
REQUESTS_FROM: dict[CommandState, frozenset[CommandState]] = {
    _S.READY_TO_READ_CURSOR: frozenset({_S.PAUSE, _S.ABORT}),
    _S.WAIT_FOR_ACK: frozenset({_S.PAUSE, _S.ABORT}),
    _S.RESEND_GCODE_COMMAND: frozenset({_S.PAUSE, _S.ABORT}),
    _S.PAUSED: frozenset({_S.RESUME, _S.ABORT}),
}


@dataclass(slots=True)
class Line:
    """One command of a stream: its index among the stream's commands and file offset.

    Not frozen: one is made for every line of a file, and a frozen dataclass sets
    each field through object.__setattr__. Nothing changes a Line once made.
    """

    index: int
    text: str
    end_offset: int = 0


def lines_from_text(text: str) -> list[Line]:
    """Commands of a script or a multi-command request (newline or `;`-free lines)."""
    from printers.protocol.checksum import clean_line

    commands = [clean_line(raw) for raw in text.splitlines()]
    return [Line(i, c) for i, c in enumerate(c for c in commands if c)]


_ids = itertools.count(1)


@dataclass(eq=False)
class Stream:
    """A spooler job: `generate()` yields its lines; counters say how far it got.

    *ref* is the caller's handle (a job id, a queued-command id); *origin* names the
    client that asked, so replies can go back to it.
    """

    type: StreamType
    lines: Iterable[Line]
    name: str = ""
    ref: object = None
    origin: str = ""
    id: int = field(default_factory=lambda: next(_ids))
    state: CommandState = CommandState.START
    sent: int = 0
    acked: int = 0
    bytes_acked: int = 0
    #: The file's commands done (acknowledged) and sent: the index after the last
    #: such line. They equal `acked` and `sent` for a whole file; a resumed run
    #: starts them at its first line, and lines skipped host-side count as done.
    done: int = 0
    reached: int = 0
    eof: bool = False
    #: The closing sync after a file stream's last line (LinkProtocol.closing_sync):
    #: "" not reached, "owed" sent and unanswered, "done" answered or not needed.
    sync: str = ""
    outcome: str = ""
    message: str = ""
    #: The printer's side of the stream (its SD card); None for a plain stream.
    printer_side: PrinterSide | None = None
    #: How many files run it ([ESP700] read from a file: 1; from that one's: 2...).
    depth: int = 0
    _reader: Iterator[Line] | None = field(default=None, repr=False)

    def generate(self) -> Iterator[Line]:
        """The stream's lines, read lazily (MeerK40t's generate())."""
        if self._reader is None:
            self._reader = iter(self.lines)
        return self._reader

    def move(self, new: CommandState) -> None:
        """Change command state, refusing moves the table above does not allow."""
        if new not in TRANSITIONS[self.state]:
            raise LocalProtocolError(
                f"stream {self.name or self.id}: can't go from {self.state.value} "
                f"to {new.value}"
            )
        self.state = new

    @property
    def finished(self) -> bool:
        return self.state is CommandState.END

    @property
    def drained(self) -> bool:
        """Every line read, sent and acknowledged, and the closing sync answered."""
        return self.eof and self.acked >= self.sent and self.sync != "owed"
