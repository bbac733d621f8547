"""The printer row's live fields (state, message, temperatures), written when they change.

Temperature samples for the chart are written here and deleted by the upkeep
(`printers/upkeep.py`, from Celery beat), never in the worker's loop.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from printers import broadcast
from printers.dbclock import shared_now
from printers.models import Printer, TemperatureSample

if TYPE_CHECKING:
    from printers.worker.lease import Lease

#: Temperatures and machine status are saved at most this often (s).
SAVE_SECONDS = 1.0
#: A temperature sample for the chart is written at most this often (s).
SAMPLE_SECONDS = 5.0


class PrinterStatus:
    """Collects what the worker learns and writes it to the printer row, throttled."""

    def __init__(self, printer_id: int, lease: Lease | None = None) -> None:
        self.printer_id = printer_id
        #: Saves commit only while this lease is held (None: unconditional).
        self.lease = lease
        self.state = Printer.State.OFFLINE
        self.message = ""
        self.fields: dict[str, Any] = {}
        self._dirty: set[str] = set()
        self._saved_state: tuple[str, str] | None = None
        self._save_at = 0.0
        self._sample_at: float | None = None

    def set_state(self, state: str, message: str = "") -> bool:
        """Change state (saved at the next save); True if it changed."""
        if (state, message) == (self.state, self.message):
            return False
        self.state, self.message = Printer.State(state), message
        return True

    def update(self, **fields: Any) -> None:
        """Remember live fields (temperatures, firmware_name...) for the next save."""
        for name, value in fields.items():
            if self.fields.get(name) != value:
                self.fields[name] = value
                self._dirty.add(name)

    def save_if_due(self, now: float, *, force: bool = False) -> None:
        """State changes are saved at once; the rest at most once a second."""
        state_changed = (self.state, self.message) != self._saved_state
        if not (state_changed or force or (self._dirty and now >= self._save_at)):
            return
        values = {name: self.fields[name] for name in self._dirty}
        values.update(state=self.state, state_message=self.message)
        if self.lease is not None:
            # The lease's own check writes them (and worker_seen_at): one UPDATE a
            # second, in plain SQL, instead of that check and an ORM update after it.
            with self.lease.held(**values):
                self._sample_if_read(now, values)
        else:
            values["worker_seen_at"] = shared_now()
            Printer.objects.filter(pk=self.printer_id).update(**values)
            self._sample_if_read(now, values)
        values.setdefault("worker_seen_at", shared_now())
        broadcast.publisher().status(self.printer_id, values)
        self._dirty.clear()
        self._saved_state = (self.state, self.message)
        self._save_at = now + SAVE_SECONDS

    def _sample_if_read(self, now: float, values: dict[str, Any]) -> None:
        if "temperatures" in values:
            self.sample(now, values["temperatures"])

    def sample(self, now: float, temperatures: dict[str, Any]) -> bool:
        """Keep a reading for the chart, at most every SAMPLE_SECONDS; True if written."""
        if not temperatures or (self._sample_at is not None and now < self._sample_at):
            return False
        TemperatureSample.objects.create(
            printer_id=self.printer_id, time=shared_now(), temperatures=temperatures
        )
        self._sample_at = now + SAMPLE_SECONDS
        return True
