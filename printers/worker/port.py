"""The worker's port: open it, say hello, lose it, retry (a mixin of PrinterWorker)."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from printers.driver import protocol_for
from printers.models import Printer
from printers.streaming import Stream, StreamType, lines_from_text
from printers.transport import PortNotAllowed, SerialTransport, TransportError
from printers.worker.emergency import EMERGENCY

if TYPE_CHECKING:
    from printers.worker.loop import PrinterWorker

__all__ = ["BACKOFF_CAP", "BACKOFF_FIRST", "PortHandling"]

logger = logging.getLogger("printhost.worker")

#: Reconnect delays after a failed open or a lost port (s), doubling up to the cap.
BACKOFF_FIRST = 0.5
BACKOFF_CAP = 30.0


class PortHandling:
    """Opening, greeting and losing the printer's port; retries with backoff."""

    def connect(self: PrinterWorker, now: float) -> None:
        """Open the port; on failure say why and retry later with backoff."""
        self.status.set_state(Printer.State.CONNECTING, f"opening {self.printer.port}")
        self.lease.ensure(now)
        try:
            self.transport = SerialTransport.open(self.printer.port, self.printer.baud)
        except PortNotAllowed as error:
            # Retrying cannot help: the port stays closed until a superuser fixes it
            # (runhost restarts a worker whose printer changed) or asks to reconnect.
            self.stay_offline = True
            logger.error("%s: %s", self.printer.slug, error)
            self.note(str(error))
            self.status.set_state(Printer.State.ERROR, str(error))
            return
        except TransportError as error:
            self._retry_later(now, str(error))
            return
        self.backoff = BACKOFF_FIRST
        self.pacer.reset()
        self.link.connected(now)
        self.protocol = protocol_for(self.config)
        self.host = self.new_host()
        if not self.halted.startswith(EMERGENCY):
            # An emergency stop ends only by an operator's reconnect: a port that
            # came back by itself (a cable, a reset board) is no one saying so.
            self.halted = ""
        self.autoreport = False
        self.emergency_parser, self.expect_reset = None, False
        # Capabilities are the connected firmware's: M115 reports them again (a
        # Cap:CANCEL_OBJECTS from an earlier firmware must not outlive it).
        self.status.update(capabilities={})
        self.prompts.clear()
        self.sd.reset()
        self.note(f"connected to {self.printer.port} at {self.printer.baud} baud")
        self.hello(now)
        self.update_state()

    def hello(self: PrinterWorker, now: float) -> None:
        """Say hello after a connect or a firmware reset: numbering, identity, scripts."""
        self.protocol.reset_line_numbers(now)
        first = "$I" if self.printer.is_grbl else "M115"
        text = "\n".join([first, self.printer.connect_script])
        self.host.submit(
            Stream(StreamType.MULTIPLE_COMMANDS, lines_from_text(text), name="hello")
        )

    def port_lost(self: PrinterWorker, message: str) -> None:
        """The port went away: stop the job (never continue blindly) and reconnect."""
        self.stop_streams(
            f"the port went away mid-job ({message}); the job was stopped",
            outcome="interrupted",
        )
        self._close()
        self._retry_later(self.clock(), f"port lost: {message}")

    def disconnect(self: PrinterWorker, message: str) -> None:
        self.stop_streams(message, outcome="interrupted")
        self._close()
        self.update_state()

    def stop_streams(
        self: PrinterWorker,
        message: str,
        *,
        outcome: str = "failed",
        note: bool = False,
    ) -> None:
        """End every stream with *message*, forget what is in flight, record outcomes."""
        self.host.fail_all(message, outcome=outcome)
        self.protocol.abandon()
        self.handle_host_events(self.clock())
        if note:
            self.note(message)

    def _retry_later(self: PrinterWorker, now: float, message: str) -> None:
        self.next_connect = now + self.backoff
        text = f"{message}; retrying in {self.backoff:.1f} s"
        self.backoff = min(self.backoff * 2, BACKOFF_CAP)
        logger.warning("%s: %s", self.printer.slug, text)
        self.note(text)
        self.status.set_state(Printer.State.OFFLINE, text)

    def _close(self: PrinterWorker) -> None:
        self.prompts.clear()
        if self.transport is not None:
            self.transport.close()
            self.transport = None
