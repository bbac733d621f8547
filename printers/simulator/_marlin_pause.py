"""M600 filament change with HOST_PROMPT_SUPPORT: park, ask the user, wait for them.

What Marlin's `feature/pause.cpp` and `feature/host_actions.cpp` print: the printer
parks, tells the host it paused itself (`//action:paused`), shows the prompt
"Nozzle Parked" with one button "Continue", and keeps saying
`echo:busy: paused for user` (host_keepalive) until the user continues it: from
the LCD (the control socket's `click`), or M108 / `M876 S0` through the emergency
parser (the only way a line reaches a firmware blocked in this loop). Then
`//action:prompt_end`, `//action:resumed` and, at last, the M600's ok.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from printers.simulator._marlin_machine import words

if TYPE_CHECKING:
    from collections.abc import Callable

    from printers.simulator._marlin_machine import Job

__all__ = ["FilamentChange"]

PROMPT = ("//action:prompt_begin Nozzle Parked", "//action:prompt_button Continue")


class FilamentChange:
    """The M600 wait loop; *print_* writes firmware lines to the host."""

    def __init__(self, print_: Callable[..., None], *, host_prompts: bool) -> None:
        self._print = print_
        self.host_prompts = host_prompts
        #: M600 is parked, waiting for the user.
        self.waiting = False
        self._continued = False
        #: Answers seen through the emergency parser or the LCD (`M876 S<n>`, ...).
        self.answers: list[str] = []

    def m600(self, args: str, now: float) -> Job:
        """Park, ask, wait (any time at all), continue."""
        self._print("echo:Nozzle parked: insert filament and continue")
        if self.host_prompts:
            self._print("//action:paused", "//action:prompt_end", *PROMPT)
            self._print("//action:prompt_show")
        self.waiting, self._continued = True, False
        while not self._continued:
            yield lambda: self._continued
        self.waiting = False
        if self.host_prompts:
            self._print("//action:prompt_end", "//action:resumed")

    def continue_(self, how: str) -> bool:
        """The user answered (M108, `M876 S0`, a click); False if nothing waits."""
        self.answers.append(how)
        if not self.waiting:
            return False
        self._continued = True
        return True

    def on_emergency(self, code: str, args: str) -> bool:
        """M108 or M876 through the emergency parser; True if M600 continues."""
        if code == "108":
            return self.continue_("M108")
        if code != "876":
            return False
        choice = int(words(args.split(";")[0]).get("S", 0.0))
        if choice != 0:  # only "Continue" (0) is a button of this prompt
            self.answers.append(f"M876 S{choice}")
            return False
        return self.continue_("M876 S0")

    def m876(self, args: str, now: float) -> None:
        """M876 from the queue: the emergency parser already acted on it."""
