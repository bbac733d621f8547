"""What any client asks of a printer, one path for all (ESP3D's message routing).

HTTP views, the slicer dialects, websockets and the terminal send commands and
actions through here: the role check, the intent written for the worker
(`jobs.commands`) and the audit entry, in that order, always. An `[ESPxxx]`
command's reply goes back to the client that asked (`wait_reply`); everything the
printer says reaches every client through the response log.
"""

from __future__ import annotations

import asyncio
from typing import TYPE_CHECKING

from channels.db import database_sync_to_async

from jobs import commands
from jobs.models import running_job
from printers.models import Printer, QueuedCommand
from printhost import audit
from printhost.models import Role

if TYPE_CHECKING:
    from printhost.access import Caller

#: Printer states in which the firmware is connected and takes commands.
ONLINE_STATES = frozenset(
    {
        Printer.State.IDLE,
        Printer.State.PRINTING,
        Printer.State.PAUSED,
        Printer.State.WAITSTART,
    }
)
#: How often (s) `wait_reply` looks for the worker's answer.
REPLY_POLL = 0.05


class PrinterOffline(ValueError):
    """A command for a printer whose firmware is not connected."""


def check_operator(caller: Caller, printer: Printer) -> None:
    """Raise PermissionError unless *caller* may act on *printer*."""
    if not caller.can(printer, Role.OPERATOR):
        raise PermissionError(f"operator role needed on printer {printer.slug!r}")


def run_command(caller: Caller, printer: Printer, text: str) -> QueuedCommand:
    """Queue a command as *caller*, audited.

    Emergencies (M112, M108, M410) are taken even while the printer is offline;
    anything else then raises PrinterOffline. An empty command raises ValueError.
    """
    check_operator(caller, printer)
    words = text.split()
    emergency = bool(words) and words[0].upper() in commands.EMERGENCY_COMMANDS
    if words and not emergency and current_state(printer) not in ONLINE_STATES:
        raise PrinterOffline("Printer offline")
    row = commands.send_command(printer, text, origin=caller.origin)
    audit.record(caller, "command", printer=printer, detail=row.text)
    return row


def current_state(printer: Printer) -> str:
    """The printer's state as its worker last wrote it.

    Websocket and terminal sessions hold their Printer row for hours; its `state`
    field is as old as the session, so read the column afresh.
    """
    state = Printer.objects.filter(pk=printer.pk).values_list("state", flat=True)
    return state.first() or Printer.State.OFFLINE


def run_action(
    caller: Caller,
    printer: Printer,
    action: str,
    *,
    audit_as: str = "",
    detail: str = "",
) -> QueuedCommand:
    """Pause, resume, abort, clear the bed, (re)connect, disconnect or stop now.

    `prompt:<n>` answers the printer's host prompt with button n (M876).
    `emergency_stop` goes out ahead of everything; the rest are requests for the
    worker's stream controller. Audited as *audit_as* (default: the action), with
    the running job.
    """
    check_operator(caller, printer)
    if action == "emergency_stop":
        row = commands.emergency_stop(printer, origin=caller.origin)
    else:
        row = commands.request_action(printer, action, origin=caller.origin)
    audit.record(
        caller,
        audit_as or action,
        printer=printer,
        job=running_job(printer.pk),
        detail=detail,
    )
    return row


async def wait_reply(row_id: int, timeout: float) -> dict[str, str] | None:
    """`{"state", "reply"}` once the worker has answered request *row_id*.

    None if it has not within *timeout* seconds (the request stays queued).
    """
    read = database_sync_to_async(_answer_of)
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        answer = await read(row_id)
        if answer is not None:
            return answer
        if loop.time() >= deadline:
            return None
        await asyncio.sleep(REPLY_POLL)


def _answer_of(row_id: int) -> dict[str, str] | None:
    row = QueuedCommand.objects.filter(pk=row_id).values("state", "reply").first()
    if row is None:
        return {"state": QueuedCommand.State.FAILED, "reply": "the request was removed"}
    done = (QueuedCommand.State.DONE, QueuedCommand.State.FAILED)
    return row if row["state"] in done else None
