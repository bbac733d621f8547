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

from printers.dbclock import OFFSET_CHECK_SECONDS, learn_offset
from printers.driver import LinkConfig, protocol_for
from printers.models import Printer
from printers.protocol.events import LineKind
from printers.protocol.pacing import Pacer
from printers.streaming import Stream, StreamHost
from printers.transport import (
    SerialTransport,
    TransportClosed,
)
from printers.worker import spool
from printers.worker.journal import Journal
from printers.worker.lease import (
    UNREACHABLE,
    DatabaseAway,
    Lease,
    LeaseLost,
    make_owner,
)
from printers.worker.linkstats import LinkStats
from printers.worker.port import BACKOFF_FIRST, PortHandling
from printers.worker.prompts import HostPrompts
from printers.worker.reactions import Reactions
from printers.worker.requests import RequestPoller
from printers.worker.responselog import ResponseLog
from printers.worker.sdcard import SdCardWatch
from printers.worker.spooling import Spooling
from printers.worker.states import PrinterStates
from printers.worker.status import PrinterStatus
from printers.worker.turns import DatabaseTurns
from printers.worker.wakeup import Wakeups

if TYPE_CHECKING:
    from collections.abc import Callable

    from printers.protocol.link import LinkProtocol

logger = logging.getLogger("printhost.worker")


class PrinterWorker(PortHandling, Reactions, Spooling, DatabaseTurns, PrinterStates):
    """Drives one printer: owns its port, protocol, stream host and database rows."""

    def __init__(
        self,
        printer: Printer,
        *,
        clock: Callable[[], float] = time.monotonic,
        owner: str = "",
        alone: bool = False,
    ) -> None:
        """*alone*: the worker has its thread's database connection to itself
        (a process of its own, run_printer): see `Wakeups.quiet`."""
        self.printer = printer
        self.config = LinkConfig.from_printer(printer)
        self.clock = clock
        self.lease = Lease(
            printer.pk, owner or make_owner(), settings.PRINTHOST_LEASE_SECONDS
        )
        self.poll_seconds = settings.PRINTHOST_POLL_SECONDS
        #: PostgreSQL's notifications wake the loop when something is written for
        #: the printer; while they do, requests and jobs are read only this often
        #: (writes keep the poll's pace).
        self.wakeups = Wakeups(printer.pk, alone=alone)
        self.fallback_poll_seconds = max(
            self.poll_seconds, settings.PRINTHOST_FALLBACK_POLL_SECONDS
        )
        #: The printer's state changed since queued jobs were last looked for.
        self.look_for_jobs = True
        self.log = ResponseLog(printer.pk, lease=self.lease)
        self.journal = Journal(printer.pk)
        self.status = PrinterStatus(printer.pk, lease=self.lease)
        self.requests = RequestPoller(self)
        self.transport: SerialTransport | None = None
        self.protocol: LinkProtocol = protocol_for(self.config)
        self.host = self.new_host()
        #: What is still on the wire, so one wake-up takes several replies.
        self.pacer = Pacer(printer.baud)
        #: The link's figures, saved with the status (`Printer.link_stats`).
        self.link = LinkStats(printer.baud)
        self.shutdown = False
        self.waitstart = False
        #: Database writes held while the database is away, in order (hold_or_run).
        self.held: list[Callable[[], object]] = []
        self.halted = ""
        self.stay_offline = False
        self.autoreport = False
        #: Cap:EMERGENCY_PARSER from this connection's M115 (None: not reported).
        self.emergency_parser: bool | None = None
        #: The firmware's host prompt (//action:prompt_*), per connection.
        self.prompts = HostPrompts(self.status)
        #: The printer's own SD card: listing, prints from it, uploads to it.
        self.sd = SdCardWatch(self)
        #: Replies are shown to the card's watch (Marlin's M20, M27, M28...).
        self.sd_replies = not printer.is_grbl
        #: An emergency DTR reset is under way: its reset banner keeps the halt.
        self.expect_reset = False
        #: A GRBL job stopped: the soft reset owed after its feed hold, by then.
        self.reset_due: float | None = None
        #: The stream a Marlin quickstop (M410) was sent for: one per stopped job.
        self.quickstopped: Stream | None = None
        self.last_stream_error = ""
        #: The start script of the job being started (its failure fails the job).
        self.start_script: Stream | None = None
        self.next_poll = 0.0
        self.next_read = 0.0
        self.next_progress = 0.0
        self.next_temperature = 0.0
        self.next_connect = 0.0
        self.next_clock_check = 0.0
        self.backoff = BACKOFF_FIRST

    # -- lifecycle ---------------------------------------------------------------

    def start(self) -> None:
        """Claim the printer and settle what a previous worker left behind."""
        self.lease.take(self.clock())
        # What this worker stamps is stamped by the database's clock (dbclock.py).
        learn_offset()
        self.next_clock_check = self.clock() + OFFSET_CHECK_SECONDS
        with self.lease.held():
            recovered = spool.recover_interrupted(self.printer.pk, self.journal.last())
        for job in recovered:
            self.note(f"job {job.pk} ({job.name}) {job.message}")
            self.waitstart = True
        self.requests.fail_orphans("the printer's worker stopped before it answered")
        waiting, self.halted = self._left_behind()
        self.waitstart = self.waitstart or waiting
        self.update_state()
        self.status.save_if_due(self.clock(), force=True)

    def run(self) -> None:
        """Tick until told to stop; an unexpected error stops the job and says why."""
        self.start()
        try:
            while not self.shutdown:
                try:
                    self.tick()
                except (DatabaseAway, *UNREACHABLE) as error:
                    # The printer goes on; what is to be written waits (lease.py).
                    if not self.lease.keep_while_away:
                        raise
                    if not isinstance(error, DatabaseAway):
                        self.lease.unreachable(error)
        except LeaseLost as error:
            self.abandon(str(error))
            raise
        except Exception as error:
            logger.exception("worker for %s crashed", self.printer.slug)
            self.crash(f"internal error in the worker: {error!r}")
            raise
        finally:
            try:
                self.stop()
            finally:
                self.wakeups.close()

    def stop(self) -> None:
        """Save everything, close the port, give the printer back.

        With the database away the port is closed all the same; what could not be
        written is left to the next worker, which settles the run from the journal.
        """
        if self.lease.lost:
            return
        try:
            self.settle_held()
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
        except (DatabaseAway, *UNREACHABLE) as error:
            self._close()
            self.journal.close()
            logger.warning(
                "%s: stopped with the database away (%s): %d response lines and "
                "%d other writes were not stored; the next worker settles the run "
                "from the journal",
                self.printer.slug, error, self.log.waiting, len(self.held),
            )  # fmt: skip
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
        transport = self.transport
        if transport is None:
            self._tick_offline(now)
            return
        protocol, lease = self.protocol, self.lease
        deadline = protocol.next_deadline()
        now, wait = self._pace(now, deadline)
        wake_by = now + wait
        lease.ensure(now)
        try:
            data = transport.read(wait, wake=self.wakeups.fileno())
            now = self.clock()
            if self.wakeups.take(readable=transport.woken):
                self.next_poll = self.next_read = wake_by = now
            if data and self.pacer.modelled:
                data, now = self._rest_of_line(data, now, wake_by)
        except TransportClosed as error:
            self.port_lost(str(error))
            return
        protocol.receive_data(data, now)
        self.handle_protocol_events(now)
        if data:
            self.link.bytes_received += len(data)
            if self.pacer.sampling(now):
                self.pacer.acknowledged(protocol.bytes_in_flight, now)
        # The deadline read before the wait, asked again only once it has passed:
        # what was read meanwhile moves deadlines on, and one it brought nearer
        # (a probe no longer held off by busy:) makes the next wait zero.
        if deadline is not None and now >= deadline:
            deadline = protocol.next_deadline()
            if deadline is not None and now >= deadline:
                protocol.handle_timeout(now)
                self.handle_protocol_events(now)
        self.pump(now)
        # Database work comes after the window was refilled, while those bytes travel.
        if now >= self.next_poll:
            self._housekeeping(now)
            self.pump(now)
        self.journal_progress()
        try:
            self.log.flush_if_due(now)
        except DatabaseAway:  # the log holds its lines until it is back (lease.py)
            return

    def journal_progress(self) -> None:
        """Append the job's acknowledged line to the journal (every tick that moved it)."""
        queue = self.host.stream_queue
        stream = queue[0] if queue else None  # the host's current_stream
        if stream is not None and spool.is_job(stream):
            self.journal.progress(
                stream.ref, stream.done, stream.reached, stream.bytes_acked
            )

    def pump(self, now: float) -> None:
        """Steps 4 and 5: advance the streams and write what is ready, in one call."""
        if self.transport is None:
            return
        host, protocol = self.host, self.protocol
        protocol.printing = host.printing
        queue = host.stream_queue
        # Only a stream with a printer's side (an SD card's) can be writing a file.
        protocol.writing_file = (
            bool(queue) and queue[0].printer_side is not None and self.sd.writing()
        )
        host.advance(now)
        if host.has_events:
            self.handle_host_events(now)
        data = protocol.data_to_send()
        if data:
            self.lease.ensure(now)
            # Timed before the write: writing wakes the reader, which may take
            # this CPU at once, so a time read after it can be late by a lot.
            written_at = self.clock()
            try:
                self.transport.write(data)
            except TransportClosed as error:
                self.port_lost(str(error))
                return
            self.pacer.wrote(len(data), written_at)
            self.link.bytes_sent += len(data)
        self.handle_protocol_events(now)

    def _pace(self, now: float, deadline: float | None) -> tuple[float, float]:
        """How long the turn may wait for the firmware: until the next deadline or
        database turn. Waits first while the wire is still busy with what was
        written (P2 in printers/protocol/pacing.py), so one wake-up takes every
        reply that came meanwhile; never past that. Returns the time after and
        what is left of the wait."""
        # The log's batches ride on the turns (flush_if_due runs every turn): a
        # wake-up of their own would be one more a quarter second.
        wake = self.next_poll
        if deadline is not None and deadline < wake:
            wake = deadline
        wait = max(0.0, min(wake - now, self._turn_seconds()))
        until = self.pacer.read_at(now, self.protocol.in_flight)
        if until <= now:
            return now, wait
        time.sleep(min(until - now, wait))
        later = self.clock()
        return later, max(0.0, wait - (later - now))

    def _rest_of_line(
        self, data: bytes, now: float, wake_by: float
    ) -> tuple[bytes, float]:
        """A read that cut a reply line: wait for its rest in this same turn (P4 in
        printers/protocol/pacing.py) rather than take a whole turn for each part.
        Never past *wake_by*, the loop's next deadline."""
        self.pacer.received(data, now)
        until = self.pacer.rest_at(now)
        if until is None:
            return data, now
        until = min(until, wake_by)
        if until > now:
            time.sleep(until - now)
        more = self.transport.read_waiting()
        now = self.clock()
        if more:
            self.pacer.received(more, now)
        return data + more, now

    def new_host(self) -> StreamHost:
        """The stream host of a connection: the printer's scripts, and on GRBL the
        abort script held until the soft reset that follows an abort (its lines
        sent before would be emptied from GRBL's buffer with the job's)."""
        return StreamHost(
            self.protocol,
            scripts=self.printer.scripts(),
            after_reset={"abort"} if self.printer.is_grbl else (),
        )

    def note(self, text: str, kind: int = LineKind.IMPORTANT) -> None:
        """A line from printhost itself in the response log (not from the firmware)."""
        self.log.add(f"[printhost] {text}", kind)
