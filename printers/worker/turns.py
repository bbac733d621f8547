"""The worker loop's database side: its turns, while connected and while offline.

A mixin of PrinterWorker (printers/worker/loop.py), like Reactions: every poll
interval (every LISTENING_TURN_SECONDS while PostgreSQL notifies) the loop renews
its lease, reads requests and jobs when there may be news (wakeup.py), and saves
progress, link figures and status; after an outage it writes what it held.
"""

from __future__ import annotations

import select
import time
from typing import TYPE_CHECKING

from printers.dbclock import OFFSET_CHECK_SECONDS, learn_offset
from printers.worker import spool
from printers.worker.emergency import reset_when_held
from printers.worker.lease import UNREACHABLE, DatabaseAway
from printhost.longrunning import close_failed_connections

if TYPE_CHECKING:
    from printers.worker.loop import PrinterWorker

__all__ = ["LISTENING_TURN_SECONDS", "PROGRESS_SECONDS", "DatabaseTurns"]

#: Job progress is saved at most this often (s).
PROGRESS_SECONDS = 1.0
#: A worker that LISTENs (PostgreSQL) is woken for whatever is written for its
#: printer: its own database turns (writes, the log's batches) come this often
#: instead of every poll interval. Each turn is a wake-up of its own while the
#: printer prints at a few lines a second, and a wake-up costs a cold loop.
LISTENING_TURN_SECONDS = 0.25


class DatabaseTurns:
    """The loop's database turns (see the module docstring)."""

    def _housekeeping(self: PrinterWorker, now: float) -> None:
        self.next_poll = now + self._turn_seconds()
        read = now >= self.next_read
        if read:
            self.next_read = now + self._read_interval()
            read = not self.wakeups.quiet(now)
        self.poll_temperature(now)
        reset_when_held(self, now)
        try:
            if not self.lease.away:
                close_failed_connections()
            self.lease.renew_if_due(now)
            if self.lease.recovered:
                self.write_held(now)
            if now >= self.next_clock_check and not self.lease.away:
                self.next_clock_check = now + OFFSET_CHECK_SECONDS
                learn_offset()
            if read:
                self._check_lease(now)
                self.requests.poll(now)
            self.maybe_claim_job(now, read=read)
            self.sd.poll(now)
            if now >= self.next_progress:
                self.next_progress = now + PROGRESS_SECONDS
                self.save_progress()
            stats = self.link.snapshot(now, self.protocol)
            if stats is not None:
                self.status.update(link_stats=stats)
            self.status.save_if_due(now)
        except (DatabaseAway, *UNREACHABLE) as error:
            if not self.lease.keep_while_away:
                raise
            if not isinstance(error, DatabaseAway):
                self.lease.unreachable(error)

    def _check_lease(self: PrinterWorker, now: float) -> None:
        """Lease.check(), unless the log stored a batch within the poll interval:
        that write ran in `Lease.held()`, which checked the same row (owner and
        expiry) more strictly, so the lease is as fresh as a check would make it.
        While printing, the log stores four times a second: a read spared each
        time."""
        if now - self.log.stored_at >= self._read_interval():
            self.lease.check()

    def write_held(self: PrinterWorker, now: float) -> None:
        """The database is back: write what waited, in order, before anything new.

        Held stream events first (a run's outcome, which also decides the bed
        must be cleared before the next job), then requests taken but never
        acted on are failed, then a run the control plane took for dead is shown
        running again, then the log, progress and status.
        """
        self.write_held_actions()
        self.requests.fail_orphans("the answer was lost while the database was away")
        stream = self.host.current_stream
        if stream is not None and stream.ref is not None and stream.type.is_stream:
            with self.lease.held():
                if spool.reassert(
                    stream, paused=self.host.queue_state.value == "paused"
                ):
                    self.note(f"job {stream.ref} went on while the database was away")
        self.lease.recovered = False
        self.log.flush()
        self.save_progress()
        self.status.save_if_due(now, force=True)

    def settle_held(self: PrinterWorker) -> None:
        """Before the worker stops: if it holds writes from an outage and the
        database answers now, write them first, in order, as a turn would have.

        Else a run that ended during the outage (completed, its bed to be cleared)
        would be left to the journal and shown interrupted, and a request answered
        then would be failed as never answered. DatabaseAway if it still does not
        answer.
        """
        if not (self.held or self.lease.away or self.lease.recovered):
            return
        now = self.clock()
        self.lease.renew_now(now)  # DatabaseAway while it does not answer
        if self.lease.recovered:
            self.write_held(now)

    def _tick_offline(self: PrinterWorker, now: float) -> None:
        if not self.stay_offline and now >= self.next_connect:
            self.connect(now)
            if self.transport is not None:
                return
        if now >= self.next_poll:
            self.next_poll = now + self.poll_seconds
            close_failed_connections()
            self.lease.renew_if_due(now)
            if self.lease.recovered:  # back while the printer is offline
                self.write_held(now)
            if now >= self.next_read:
                self.next_read = now + self._read_interval()
                self.lease.check()
                self.requests.poll(now)
            self.status.save_if_due(now)
            self.log.flush_if_due(now)
        wake = self.next_poll
        if not self.stay_offline:
            wake = min(wake, self.next_connect)
        seconds = max(0.0, min(wake - now, self.poll_seconds))
        fd = self.wakeups.fileno()
        if fd is None:
            time.sleep(seconds)
            return
        readable, _, _ = select.select([fd], [], [], seconds)
        if self.wakeups.take(readable=bool(readable)):
            self.next_poll = self.next_read = self.clock()

    def _turn_seconds(self: PrinterWorker) -> float:
        """How often the loop does its database work: every poll, or every
        LISTENING_TURN_SECONDS while notifications wake it for requests."""
        if self.wakeups.listening:
            return max(self.poll_seconds, LISTENING_TURN_SECONDS)
        return self.poll_seconds

    def _read_interval(self: PrinterWorker) -> float:
        """How long until requests and jobs are read again: rarely while
        notifications wake the loop (printers/worker/wakeup.py), else every poll."""
        if self.wakeups.listening:
            return self.fallback_poll_seconds
        return self.poll_seconds
