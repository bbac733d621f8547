"""Marlin's CANCEL_OBJECTS (M486) for the simulator: which object runs, which are cancelled.

What the firmware does (Marlin's feature/cancel_object and G0/G1's destination):
objects are numbered 0-31; `M486 S<n>` says object n's moves follow (`S-1`: none),
`M486 P<n>` cancels n, `U<n>` takes that back, `C` cancels the running one, `T<n>`
says how many there are (and forgets the cancels). While the running object is
cancelled, a move leaves X, Y and Z where they are and E only counts (the
extruder does not turn). `M486` alone reports `Active Object:` and `Canceled:`.

Marlin's M115 reports no capability for it; this simulator adds
`Cap:CANCEL_OBJECTS:1` when the option is on, the line printhost reads (see
printers/worker/requests.py `firmware_cancels`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Callable

    from printers.simulator._marlin_machine import Handler, Job

__all__ = ["CancelObjects"]

#: Marlin keeps the cancelled objects in one 32-bit mask.
MAX_OBJECTS = 32
_MOVES = ("G0", "G1", "G2", "G3")


def _words(args: str) -> dict[str, int]:
    out = {}
    for word in args.split():
        letter, value = word[0].upper(), word[1:]
        try:
            out[letter] = int(float(value)) if value else 0
        except ValueError:
            continue
    return out


class CancelObjects:
    """The M486 state of one firmware run (a reset makes a new one)."""

    def __init__(self, output: Callable[..., None]) -> None:
        self._print = output
        self.active = -1
        self.count = 0
        self.cancelled: set[int] = set()
        #: Moves whose X, Y, Z and extrusion were skipped (for tests and `stats`).
        self.skipped_moves = 0

    @property
    def skipping(self) -> bool:
        return self.active in self.cancelled

    def m486(self, args: str, now: float) -> None:
        given = _words(args)
        if "T" in given:
            self.count, self.active = given["T"], -1
            self.cancelled.clear()
        if "S" in given:
            self.active = given["S"] if 0 <= given["S"] < MAX_OBJECTS else -1
            self.count = max(self.count, self.active + 1)
        if "P" in given and 0 <= given["P"] < MAX_OBJECTS:
            self.cancelled.add(given["P"])
        if "U" in given:
            self.cancelled.discard(given["U"])
        if "C" in given and self.active >= 0:
            self.cancelled.add(self.active)
        if not given:
            self._report()

    def _report(self) -> None:
        if self.active >= 0:
            self._print(f"echo:Active Object: {self.active}")
        if self.cancelled:
            numbers = " ".join(str(n) for n in sorted(self.cancelled))
            self._print(f"echo:Canceled: {numbers}")

    def wrap(self, table: dict[str, Handler]) -> None:
        """Add M486 to *table* and make its moves skip while the object is cancelled."""
        table["M486"] = self.m486
        for code in _MOVES:
            if code in table:
                table[code] = self._skipping_move(table[code])

    def _skipping_move(self, move: Handler) -> Handler:
        def handler(args: str, now: float) -> Job | None:
            if not self.skipping:
                return move(args, now)
            self.skipped_moves += 1
            # X, Y, Z stay; E (and F) still count, as Marlin's destination does.
            kept = " ".join(w for w in args.split() if w[:1].upper() in "EF")
            return move(f" {kept}" if kept else "", now)

        return handler
