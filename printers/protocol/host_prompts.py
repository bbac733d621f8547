"""Marlin's host prompts: a dialog the firmware asks the host to show, answered with M876.

With HOST_PROMPT_SUPPORT the firmware builds a dialog out of action lines
(`Marlin/src/feature/host_actions.cpp`), for example when M600 parked the nozzle:

    //action:prompt_end
    //action:prompt_begin Nozzle Parked
    //action:prompt_button Continue          (older firmware: prompt_choice)
    //action:prompt_show

The host shows "Nozzle Parked" with one button; the operator's choice goes back as
`M876 S<index>` (0 for the first button). `prompt_end` takes the dialog away (the
firmware was answered some other way, from its own display for example).

Sans-IO: `PromptTracker.on_action(action, argument)` takes the parts of a
`//action:` line (`events.ActionCommand`) and returns what changed for the host to
show, or None.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["HostPrompt", "PromptClosed", "PromptError", "PromptShown", "PromptTracker"]

#: Buttons a dialog may have; Marlin's own dialogs have at most a few.
MAX_CHOICES = 8


class PromptError(ValueError):
    """The answer does not fit the dialog shown (no dialog, or no such button)."""


@dataclass(frozen=True, slots=True)
class HostPrompt:
    """A dialog from the firmware: its text and its buttons, first is index 0."""

    message: str
    choices: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class PromptShown:
    prompt: HostPrompt


@dataclass(frozen=True, slots=True)
class PromptClosed:
    """The dialog is gone: answered here (*answer* is the button) or by the firmware."""

    answer: int | None = None


class PromptTracker:
    """Builds the firmware's dialog from action lines and checks the answer to it."""

    def __init__(self) -> None:
        self._message: str | None = None
        self._choices: list[str] = []
        self.shown: HostPrompt | None = None

    def on_action(
        self, action: str, argument: str
    ) -> PromptShown | PromptClosed | None:
        """One `//action:<action> <argument>` line; what changed, if anything."""
        match action.lower():
            case "prompt_begin":
                closed = self._close()
                self._message, self._choices = argument, []
                return closed
            case "prompt_button" | "prompt_choice":
                if self._message is not None and len(self._choices) < MAX_CHOICES:
                    self._choices.append(argument)
                return None
            case "prompt_show":
                if self._message is None:
                    return None
                self.shown = HostPrompt(self._message, tuple(self._choices))
                return PromptShown(self.shown)
            case "prompt_end":
                return self._close()
        return None

    def answer(self, choice: int) -> str:
        """The command that picks button *choice* (`M876 S<choice>`); closes the dialog."""
        shown = self.shown
        if shown is None:
            raise PromptError("the printer is not asking anything now")
        buttons = max(1, len(shown.choices))
        if not 0 <= choice < buttons:
            raise PromptError(
                f"choice {choice} is not one of the {buttons} the printer offers"
            )
        self._message, self._choices, self.shown = None, [], None
        return f"M876 S{choice}"

    def _close(self) -> PromptClosed | None:
        was_shown = self.shown is not None
        self._message, self._choices, self.shown = None, [], None
        return PromptClosed() if was_shown else None
