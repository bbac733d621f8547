"""The printer's state as the worker derives it, and what a new worker takes over
from the row (a mixin of PrinterWorker, like Reactions)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from printers.models import Printer
from printers.streaming import QueueState
from printers.worker.emergency import EMERGENCY

if TYPE_CHECKING:
    from printers.worker.loop import PrinterWorker

__all__ = ["PrinterStates"]


class PrinterStates:
    """`update_state` after anything that may change the printer's state."""

    def update_state(self: PrinterWorker) -> None:
        """Derive the printer's state from the link, the queues and waitstart."""
        before = self.status.state
        self._derive_state()
        if self.status.state != before:
            self.look_for_jobs = True
        # Kept in the row: a worker started again (a crash, a restart, an upgrade)
        # must not let the next job start on a printer stopped in an emergency.
        halt = self.halted if self.halted.startswith(EMERGENCY) else ""
        self.status.update(emergency_halt=halt)

    def _derive_state(self: PrinterWorker) -> None:
        if self.transport is None:
            if self.status.state not in (
                Printer.State.OFFLINE,
                Printer.State.CONNECTING,
            ):
                self.status.set_state(Printer.State.OFFLINE, "disconnected")
            return
        if self.halted:
            self.status.set_state(Printer.State.ERROR, self.halted)
            return
        queue = self.host.queue_state
        waiting = self.prompts.waiting_for()
        if queue is QueueState.PROCESSING:
            self.status.set_state(Printer.State.PRINTING, waiting)
        elif queue is QueueState.PAUSED:
            self.status.set_state(Printer.State.PAUSED, waiting)
        elif self.waitstart:
            self.status.set_state(
                Printer.State.WAITSTART,
                "clear the bed, then confirm to start the next job",
            )
        else:
            self.status.set_state(Printer.State.IDLE, waiting)

    def _left_behind(self: PrinterWorker) -> tuple[bool, str]:
        """What the previous worker left in the row that still holds: its waitstart
        (the bed to be cleared) and an emergency stop's halt."""
        row = (
            Printer.objects.filter(pk=self.printer.pk)
            .values("state", "emergency_halt")
            .first()
        ) or {"state": "", "emergency_halt": ""}
        if row["emergency_halt"]:
            self.note(f"{row['emergency_halt']} (kept from before this worker started)")
        return row["state"] == Printer.State.WAITSTART, row["emergency_halt"]
