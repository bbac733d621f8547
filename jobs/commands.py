"""What clients may ask of a printer's worker: commands, emergencies and actions.

Each is validated and written as a QueuedCommand row, then returned; the printer's
worker picks the rows up (printers/worker/requests.py). Nothing here touches a port.
"""

from __future__ import annotations

from printers.models import Printer, QueuedCommand

__all__ = ["EMERGENCY_COMMANDS", "emergency_stop", "request_action", "send_command"]

#: Commands that must skip every queue (Marlin's emergency parser set).
EMERGENCY_COMMANDS = frozenset({"M112", "M108", "M410"})


def send_command(printer: Printer, text: str, *, origin: str = "") -> QueuedCommand:
    """Queue a command (or several lines) for the printer; emergencies skip the queue.

    Only blanks and line ends are trimmed: Python counts GRBL's realtime bytes 0x84
    and 0x85 (jog cancel) as whitespace too.
    """
    text = text.strip(" \t\r\n")
    if not text:
        raise ValueError("empty command")
    if "\x00" in text:
        raise ValueError("a command cannot hold a NUL byte")
    word = text.split()[0].upper() if text.split() else ""
    kind = (
        QueuedCommand.Kind.EMERGENCY
        if word in EMERGENCY_COMMANDS and "\n" not in text
        else QueuedCommand.Kind.COMMAND
    )
    return QueuedCommand.objects.create(
        printer=printer, kind=kind, text=text, origin=origin
    )


def emergency_stop(printer: Printer, *, origin: str = "") -> QueuedCommand:
    """Stop the machine now: M112 (Marlin) or feed hold + soft reset (GRBL)."""
    return QueuedCommand.objects.create(
        printer=printer, kind=QueuedCommand.Kind.EMERGENCY, text="M112", origin=origin
    )


def request_action(printer: Printer, action: str, *, origin: str = "") -> QueuedCommand:
    """Ask the worker to pause, resume, abort, accept a clear bed or reconnect.

    `prompt:<n>` answers the printer's host prompt with button n (the worker checks
    it against the dialog shown).
    """
    prompt = f"{QueuedCommand.Action.PROMPT}:"
    if action.startswith(f"{QueuedCommand.Action.SD_DELETE}:"):
        from jobs.sdcard import card_name

        card_name(action.partition(":")[2])  # SdRefused (a ValueError) if unusable
    elif action.startswith(prompt):
        choice = action[len(prompt) :]
        if not (choice.isascii() and choice.isdigit() and len(choice) <= 2):
            raise ValueError(
                f"the prompt's choice must be a button index, not {choice!r}"
            )
    elif action not in QueuedCommand.Action.values or action in (
        QueuedCommand.Action.PROMPT,
        QueuedCommand.Action.SD_DELETE,
    ):
        raise ValueError(
            f"unknown action {action!r}; use one of {', '.join(QueuedCommand.Action.values)}"
        )
    return QueuedCommand.objects.create(
        printer=printer, kind=QueuedCommand.Kind.ACTION, text=action, origin=origin
    )
