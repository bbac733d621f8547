"""The firmware's host prompt (Marlin HOST_PROMPT_SUPPORT) as the worker shows it.

A `PromptTracker` per connection builds the dialog out of `//action:prompt_*` lines;
the shown dialog goes to `machine_status["prompt"]` (API, websocket, UI) as
`{"message", "choices", "answerable"}`. *answerable* is True only when the printer
reported `Cap:EMERGENCY_PARSER:1`: M876 then reaches a firmware blocked in M600's
wait loop; otherwise the answer may only work from the printer's own display.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from printers.protocol.host_prompts import (
    PromptClosed,
    PromptError,
    PromptShown,
    PromptTracker,
)

if TYPE_CHECKING:
    from printers.worker.status import PrinterStatus

__all__ = ["HostPrompts", "PromptError"]

#: Said when the emergency parser is not known to be on.
DISPLAY_HINT = "answer on the printer's display if this does not continue it"


class HostPrompts:
    """One connection's dialog: built from action lines, answered with M876."""

    def __init__(self, status: PrinterStatus) -> None:
        self._status = status
        self._tracker = PromptTracker()
        self.answerable = False

    def on_action(self, action: str, argument: str, *, answerable: bool) -> None:
        """A `//action:prompt_*` line; the stored dialog follows what it changed."""
        change = self._tracker.on_action(action, argument)
        if isinstance(change, PromptShown):
            self.answerable = answerable
            self._store()
        elif isinstance(change, PromptClosed):
            self._store()

    def answer(self, choice: int) -> str:
        """`M876 S<choice>` for the shown dialog (PromptError if it does not fit)."""
        command = self._tracker.answer(choice)
        self._store()
        return command

    def clear(self) -> None:
        """Forget the dialog (connect, firmware reset, port closed)."""
        self._tracker.on_action("prompt_end", "")
        self._store(force=True)

    def waiting_for(self) -> str:
        """What the printer waits for, for the state message ("" when nothing)."""
        shown = self._tracker.shown
        if shown is None:
            return ""
        text = f"waiting for the user: {shown.message}"
        if shown.choices:
            text += " — " + " / ".join(shown.choices)
        if not self.answerable:
            text += f" ({DISPLAY_HINT})"
        return text

    def _store(self, *, force: bool = False) -> None:
        status = dict(self._status.fields.get("machine_status") or {})
        shown = self._tracker.shown
        if shown is None:
            if "prompt" not in status and not force:
                return
            status.pop("prompt", None)
        else:
            status["prompt"] = {
                "message": shown.message,
                "choices": list(shown.choices),
                "answerable": self.answerable,
            }
        self._status.update(machine_status=status)
