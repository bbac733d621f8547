"""What an M112 needs beyond the line itself, and which path the stop took; and
how a GRBL job that ends before its end stops the machine (`hold_then_reset`).

Marlin acts on M112 the moment it arrives only with its emergency parser
(`Cap:EMERGENCY_PARSER:1` in the M115 reply). Stock builds have it off: there M112
waits in the RX buffer behind every command already buffered, and the planner runs
its moves first. Then the only fast stop left to the host is resetting the board,
which the usual USB boards (Arduino Mega/RAMPS, most 8-bit and many 32-bit boards)
do on a DTR pulse: the planner and buffers are gone without running.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from printers.worker.loop import PrinterWorker

#: How an emergency stop's halt begins: only an operator's reconnect ends it.
EMERGENCY = "emergency stop"
#: After the feed hold that ends a GRBL job, how long GRBL has to come to rest
#: before it is reset all the same (s): a reset while it still decelerates loses
#: its position (ALARM:3), a machine left running is worse.
HOLD_SETTLE_SECONDS = 2.0


def after_m112(worker: PrinterWorker, who: str) -> str:
    """Called once M112 is on the wire: reset the board if needed; returns the path.

    The path goes into the request's reply, a response-log note and (when the
    board was reset) the printer's state message.
    """
    if worker.transport is None:
        return ""  # the write failed: the caller says so
    if worker.printer.is_grbl:
        # The soft reset's banner must not clear the halt (`_on_reset`): a reset
        # with nothing moving leaves GRBL unlocked, and the next job would run.
        worker.expect_reset = True
        worker.note(f"emergency stop{who}: feed hold and soft reset sent")
        worker.halted = f"{EMERGENCY}{who}: reconnect to run jobs again"
        return ""
    if worker.emergency_parser:
        path = "M112 sent; the firmware's emergency parser acts on it at once"
        worker.note(f"emergency stop{who}: {path}")
        worker.halted = f"{EMERGENCY}{who}: {path}; reset the printer, then reconnect"
        return path
    why = (
        "the firmware has no emergency parser"
        if worker.emergency_parser is False
        else "the firmware did not report an emergency parser"
    )
    error = worker.transport.pulse_dtr()
    if error:
        path = (
            f"M112 sent, but {why}, so it waits behind the commands the firmware "
            f"already buffered; the board could not be reset: {error}"
        )
    else:
        worker.expect_reset = True
        path = (
            f"M112 sent and the board reset by a DTR pulse ({why}); "
            "its buffered moves were dropped"
        )
    worker.note(f"emergency stop{who}: {path}")
    worker.halted = f"{EMERGENCY}{who}: {path}; home before printing again"
    return path


def hold_then_reset(worker: PrinterWorker, now: float) -> None:
    """A GRBL job ended before its end (aborted, failed): stop the machine.

    GRBL runs what it buffered (its RX buffer and planner) whatever the host does
    next, spindle or laser on: a feed hold now, then a soft reset once it is held
    (`reset_when_held`), which empties its buffers and turns the spindle and
    coolant off while keeping its position. Jobs wait for the reset's banner.
    """
    if worker.expect_reset or worker.reset_due is not None:
        return  # a reset is on its way already (an emergency stop sent one)
    worker.protocol.send_emergency("!", now)
    worker.reset_due = now + HOLD_SETTLE_SECONDS


def reset_when_held(worker: PrinterWorker, now: float, state: str = "") -> None:
    """The soft reset `hold_then_reset` owes: once GRBL reports *state* `Hold:0`
    (held) or `Idle`, or HOLD_SETTLE_SECONDS after the hold."""
    due = worker.reset_due
    if due is None or (now < due and state not in ("Hold:0", "Idle")):
        return
    worker.reset_due = None
    if worker.transport is None:
        return  # the port went away: nothing to reset, the board is on its own
    worker.expect_reset = True
    worker.protocol.send_emergency("\x18", now)
    worker.note("GRBL reset after the job stopped: its buffers and spindle cleared")
