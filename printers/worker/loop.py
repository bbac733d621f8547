"""The printer worker: one loop that is the printer's spooler (MeerK40t) and ESP3D's host.

Each `tick()` is ESP3D's operations loop:
  1. read the link (waiting at most until the next deadline) and feed the protocol;
  2. react to the protocol's events (acks, resends, reports, resets, failures);
  3. every poll interval, take external requests written to the database;
  4. let the stream host choose the active queue and move its command states;
  5. write what the protocol has to send, in one call;
  6. flush the response log, save progress, renew the lease when due.
No threads: the only wait is the read timeout.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

from django.conf import settings
from django.db import close_old_connections

from printers.driver import LinkConfig, protocol_for
from printers.models import Printer
from printers.protocol.events import LineKind
from printers.streaming import Stream, StreamHost, StreamType, lines_from_text
from printers.transport import (
    PortNotAllowed,
    SerialTransport,
    TransportClosed,
    TransportError,
)
from printers.worker import spool
from printers.worker.journal import Entry, Journal
from printers.worker.lease import Lease, LeaseLost, make_owner
from printers.worker.prompts import HostPrompts
from printers.worker.reactions import Reactions
from printers.worker.requests import RequestPoller
from printers.worker.responselog import ResponseLog
from printers.worker.sdcard import SdCardWatch
from printers.worker.status import PrinterStatus

if TYPE_CHECKING:
    from collections.abc import Callable

    from printers.protocol.link import LinkProtocol

logger = logging.getLogger("printhost.worker")

#: Reconnect delays after a failed open or a lost port (s), doubling up to the cap.
BACKOFF_FIRST = 0.5
BACKOFF_CAP = 30.0
#: Job progress is saved at most this often (s).
PROGRESS_SECONDS = 1.0


class PrinterWorker(Reactions):
    """Drives one printer: owns its port, protocol, stream host and database rows."""

    def __init__(
        self,
        printer: Printer,
        *,
        clock: Callable[[], float] = time.monotonic,
        owner: str = "",
    ) -> None:
        self.printer = printer
        self.config = LinkConfig.from_printer(printer)
        self.clock = clock
        self.lease = Lease(
            printer.pk, owner or make_owner(), settings.PRINTHOST_LEASE_SECONDS
        )
        self.poll_seconds = settings.PRINTHOST_POLL_SECONDS
        self.log = ResponseLog(printer.pk, lease=self.lease)
        self.journal = Journal(printer.pk)
        self.status = PrinterStatus(printer.pk, lease=self.lease)
        self.requests = RequestPoller(self)
        self.transport: SerialTransport | None = None
        self.protocol: LinkProtocol = protocol_for(self.config)
        self.host = StreamHost(self.protocol, scripts=printer.scripts())
        self.shutdown = False
        self.waitstart = False
        self.halted = ""
        self.stay_offline = False
        self.autoreport = False
        #: Cap:EMERGENCY_PARSER from this connection's M115 (None: not reported).
        self.emergency_parser: bool | None = None
        #: The firmware's host prompt (//action:prompt_*), per connection.
        self.prompts = HostPrompts(self.status)
        #: The printer's own SD card: listing, prints from it, uploads to it.
        self.sd = SdCardWatch(self)
        #: An emergency DTR reset is under way: its reset banner keeps the halt.
        self.expect_reset = False
        self.last_stream_error = ""
        self.next_poll = 0.0
        self.next_progress = 0.0
        self.next_temperature = 0.0
        self.next_connect = 0.0
        self.backoff = BACKOFF_FIRST

    # -- lifecycle ---------------------------------------------------------------

    def start(self) -> None:
        """Claim the printer and settle what a previous worker left behind."""
        self.lease.take(self.clock())
        with self.lease.held():
            recovered = spool.recover_interrupted(self.printer.pk, self.journal.last())
        for job in recovered:
            self.note(f"job {job.pk} ({job.name}) {job.message}")
            self.waitstart = True
        self.waitstart = self.waitstart or self._was_waiting()
        self.update_state()
        self.status.save_if_due(self.clock(), force=True)

    def run(self) -> None:
        """Tick until told to stop; an unexpected error stops the job and says why."""
        self.start()
        try:
            while not self.shutdown:
                self.tick()
        except LeaseLost as error:
            self.abandon(str(error))
            raise
        except Exception as error:
            logger.exception("worker for %s crashed", self.printer.slug)
            self.crash(f"internal error in the worker: {error!r}")
            raise
        finally:
            self.stop()

    def stop(self) -> None:
        """Save everything, close the port, give the printer back."""
        if self.lease.lost:
            return
        try:
            stream = self.host.current_stream
            if stream is not None and stream.ref is not None:
                self.stop_streams(
                    "the worker was stopped mid-job", outcome="interrupted"
                )
            self._close()
            self.status.set_state(Printer.State.OFFLINE, "worker stopped")
            self.status.save_if_due(self.clock(), force=True)
            self.log.flush()
        except LeaseLost as error:
            self.abandon(str(error))
            return
        self.journal.close()
        self.lease.release()

    def crash(self, message: str) -> None:
        """Klipper's instinct: on a bug, stop streaming and record why."""
        try:
            self.stop_streams(message)
            self.halted = message
            self.update_state()
        except LeaseLost as error:
            self.abandon(str(error))

    def abandon(self, reason: str) -> None:
        """The lease is gone: let go of the port at once and write nothing more.

        The new holder owns the printer's rows, jobs and journal now; whatever this
        worker still had unsaved is dropped, not written over theirs.
        """
        self.lease.lost = True
        logger.error("%s: %s; stopping without writing", self.printer.slug, reason)
        self._close()
        self.journal.close()
        self.log.discard()
        self.shutdown = True

    # -- the loop ----------------------------------------------------------------

    def tick(self) -> None:
        """One turn of the operations loop (tests call this directly)."""
        now = self.clock()
        if self.transport is None:
            self._tick_offline(now)
            return
        self.lease.ensure(now)
        try:
            data = self.transport.read(self._wait_time(now))
        except TransportClosed as error:
            self.port_lost(str(error))
            return
        now = self.clock()
        self.protocol.receive_data(data, now)
        self.handle_protocol_events(now)
        deadline = self.protocol.next_deadline()
        if deadline is not None and now >= deadline:
            self.protocol.handle_timeout(now)
            self.handle_protocol_events(now)
        self.pump(now)
        # Database work comes after the window was refilled, while those bytes travel.
        if now >= self.next_poll:
            self._housekeeping(now)
            self.pump(now)
        self.journal_progress()
        self.log.flush_if_due(now)

    def journal_progress(self) -> None:
        """Append the job's acknowledged line to the journal (every tick that moved it)."""
        stream = self.host.current_stream
        if stream is not None and isinstance(stream.ref, int) and stream.type.is_stream:
            self.journal.record(
                Entry(stream.ref, stream.done, stream.reached, stream.bytes_acked)
            )

    def pump(self, now: float) -> None:
        """Steps 4 and 5: advance the streams and write what is ready, in one call."""
        if self.transport is None:
            return
        self.protocol.printing = self.host.printing
        self.protocol.writing_file = self.sd.writing()
        self.host.advance(now)
        self.handle_host_events(now)
        data = self.protocol.data_to_send()
        if data:
            self.lease.ensure(now)
            try:
                self.transport.write(data)
            except TransportClosed as error:
                self.port_lost(str(error))
                return
        self.handle_protocol_events(now)

    def _housekeeping(self, now: float) -> None:
        self.next_poll = now + self.poll_seconds
        close_old_connections()
        self.lease.renew_if_due(now)
        self.lease.check()
        self.requests.poll(now)
        self.maybe_claim_job(now)
        self.poll_temperature(now)
        self.sd.poll(now)
        if now >= self.next_progress:
            self.next_progress = now + PROGRESS_SECONDS
            self.save_progress()
        self.status.save_if_due(now)

    def _tick_offline(self, now: float) -> None:
        if not self.stay_offline and now >= self.next_connect:
            self.connect(now)
            if self.transport is not None:
                return
        if now >= self.next_poll:
            self.next_poll = now + self.poll_seconds
            close_old_connections()
            self.lease.renew_if_due(now)
            self.lease.check()
            self.requests.poll(now)
            self.status.save_if_due(now)
            self.log.flush_if_due(now)
        wake = self.next_poll
        if not self.stay_offline:
            wake = min(wake, self.next_connect)
        time.sleep(max(0.0, min(wake - now, self.poll_seconds)))

    def _wait_time(self, now: float) -> float:
        wake = min(self.next_poll, self.log.due(now))
        deadline = self.protocol.next_deadline()
        if deadline is not None:
            wake = min(wake, deadline)
        return max(0.0, min(wake - now, self.poll_seconds))

    # -- the port ----------------------------------------------------------------

    def connect(self, now: float) -> None:
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
        self.protocol = protocol_for(self.config)
        self.host = StreamHost(self.protocol, scripts=self.printer.scripts())
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

    def hello(self, now: float) -> None:
        """Say hello after a connect or a firmware reset: numbering, identity, scripts."""
        self.protocol.reset_line_numbers(now)
        first = "$I" if self.printer.is_grbl else "M115"
        text = "\n".join([first, self.printer.connect_script])
        self.host.submit(
            Stream(StreamType.MULTIPLE_COMMANDS, lines_from_text(text), name="hello")
        )

    def port_lost(self, message: str) -> None:
        """The port went away: stop the job (never continue blindly) and reconnect."""
        self.stop_streams(
            f"the port went away mid-job ({message}); the job was stopped",
            outcome="interrupted",
        )
        self._close()
        self._retry_later(self.clock(), f"port lost: {message}")

    def disconnect(self, message: str) -> None:
        self.stop_streams(message, outcome="interrupted")
        self._close()
        self.update_state()

    def stop_streams(
        self, message: str, *, outcome: str = "failed", note: bool = False
    ) -> None:
        """End every stream with *message*, forget what is in flight, record outcomes."""
        self.host.fail_all(message, outcome=outcome)
        self.protocol.abandon()
        self.handle_host_events(self.clock())
        if note:
            self.note(message)

    def _retry_later(self, now: float, message: str) -> None:
        self.next_connect = now + self.backoff
        text = f"{message}; retrying in {self.backoff:.1f} s"
        self.backoff = min(self.backoff * 2, BACKOFF_CAP)
        logger.warning("%s: %s", self.printer.slug, text)
        self.note(text)
        self.status.set_state(Printer.State.OFFLINE, text)

    def _close(self) -> None:
        self.prompts.clear()
        if self.transport is not None:
            self.transport.close()
            self.transport = None

    # -- state -------------------------------------------------------------------

    def update_state(self) -> None:
        """Derive the printer's state from the link, the queues and waitstart."""
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
        queue = self.host.queue_state.value
        waiting = self.prompts.waiting_for()
        if queue == "processing":
            self.status.set_state(Printer.State.PRINTING, waiting)
        elif queue == "paused":
            self.status.set_state(Printer.State.PAUSED, waiting)
        elif self.waitstart:
            self.status.set_state(
                Printer.State.WAITSTART,
                "clear the bed, then confirm to start the next job",
            )
        else:
            self.status.set_state(Printer.State.IDLE, waiting)

    def note(self, text: str, kind: int = LineKind.IMPORTANT) -> None:
        """A line from printhost itself in the response log (not from the firmware)."""
        self.log.add(f"[printhost] {text}", kind)

    def _was_waiting(self) -> bool:
        return (
            Printer.objects.filter(pk=self.printer.pk)
            .values_list("state", flat=True)
            .first()
            == Printer.State.WAITSTART
        )
