"""The printer's side of a stream: what the printer itself does beyond taking lines."""

from __future__ import annotations

from dataclasses import dataclass, field

from printers.streaming.streams import (
    CommandState,
    Stream,
    StreamType,
    lines_from_text,
)

__all__ = [
    "PrinterSide",
    "complete",
    "control_stream",
    "exclusive_now",
    "holding",
    "runs_scripts",
]


@dataclass(eq=False)
class PrinterSide:
    """What the printer itself does for a stream, beyond taking its lines.

    A print from the printer's SD card sends `M23 <name>`, `M24` and then the printer
    runs the file by itself (*runs_file*): the stream stays until `StreamHost.
    printer_done`. An upload to the card sends `M28 <name>`, the file's lines and
    `M29`; it is *exclusive* (the firmware writes every line it gets into the file,
    so nothing else may go until it ends) and holds after *hold_after* lines until
    `StreamHost.release` (the printer said it opened the file: a line sent to a card
    that failed to open would be run, not written); if every line before the hold is
    acknowledged and no release came, the stream fails with *hold_reason*.

    *controls* are the printer's own commands for `pause`, `resume` and `abort` (M25,
    M24, M524; an upload's abort closes and deletes the file); they go before the
    printer's pause and abort scripts and after its resume script, which run only
    with *scripts*. Without *pausable*, a pause request is refused with *why_not*.
    """

    #: The printer's file the stream is about (a name on its SD card).
    file: str = ""
    runs_file: bool = False
    exclusive: bool = False
    hold_after: int = 0
    hold_reason: str = ""
    controls: dict[str, str] = field(default_factory=dict)
    scripts: bool = True
    pausable: bool = True
    why_not: str = ""
    #: Set by StreamHost.release / printer_done.
    released: bool = False
    done: bool = False


def exclusive_now(stream: Stream) -> bool:
    """An exclusive stream that has started: only its lines may go."""
    side = stream.printer_side
    return (
        side is not None
        and side.exclusive
        and stream.state not in (CommandState.START, CommandState.END)
    )


def holding(stream: Stream) -> bool:
    """The stream sent its lines up to the hold and waits for `release`."""
    side = stream.printer_side
    return (
        side is not None
        and side.hold_after > 0
        and not side.released
        and stream.sent >= side.hold_after
    )


def complete(stream: Stream) -> bool:
    """Every line acknowledged and, for a file the printer runs, the printer done."""
    side = stream.printer_side
    return stream.drained and (side is None or not side.runs_file or side.done)


def runs_scripts(stream: Stream) -> bool:
    side = stream.printer_side
    return side is None or side.scripts


def control_stream(stream: Stream, action: str) -> Stream | None:
    """The printer's own commands for *action* (M25, M24, M524, M29...) as a script."""
    side = stream.printer_side
    lines = lines_from_text(side.controls.get(action, "")) if side else []
    if not lines:
        return None
    return Stream(StreamType.MULTIPLE_COMMANDS, lines, name=f"{action} ({stream.name})")
