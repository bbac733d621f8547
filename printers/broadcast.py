"""Everything that sends into the printers' channel-layer groups: the live feed's source.

- **Worker side** (`LivePublisher`): when the channel layer crosses processes (Redis),
  the worker publishes right after it wrote the rows, so a consumer can always fill a
  gap from the database. One private event loop, no threads; a failing Redis costs at
  most one short timeout, then messages are dropped for a while.
- **Serving side without Redis** (`Relay`): the process serving clients (daphne, the
  terminal) polls the database every 0.25 s per watched printer and sends into its
  in-process layer; `watch` / `unwatch` start it with a printer's first client and
  stop it after its last.

A message on a group is `{"type": "live.event", "printer_id": id, "event": {...}}`;
what clients do with it is in `printers.live` and `printers.consumers`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from channels.db import database_sync_to_async
from channels.layers import InMemoryChannelLayer, get_channel_layer

from jobs.models import ACTIVE_STATES, Job
from printers.live import (
    PAGE_LINES,
    current_job,
    group_for,
    line_dict,
    lines_after,
    log_bounds,
    state_of,
)
from printers.models import Printer

if TYPE_CHECKING:
    from collections.abc import Iterable
    from datetime import datetime

logger = logging.getLogger("printhost.live")

#: How often the in-process relay looks for new rows (s).
RELAY_SECONDS = 0.25
#: A publish to the layer waits at most this long (s).
SEND_TIMEOUT = 0.5
#: After a failed publish, drop messages for this long (s) before trying again.
PAUSE_AFTER_FAILURE = 5.0
#: A failing layer is logged at most this often (s).
LOG_EVERY = 60.0
#: A running job's progress is published from the row read at most this long ago
#: (s) with the worker's own counters: once a second, the read cost more than the
#: rest of the publish. Anything else about the job re-reads it at once.
JOB_REREAD_SECONDS = 10.0
#: Printer fields sent as `state` (temperatures have their own message).
STATE_FIELDS = (
    "state",
    "state_message",
    "firmware_name",
    "machine_status",
    "sd_card",
)


def layer_crosses_processes() -> bool:
    """True when the layer reaches other processes (Redis): the worker publishes."""
    layer = get_channel_layer()
    return layer is not None and not isinstance(layer, InMemoryChannelLayer)


def message(printer_id: int, event: dict[str, Any]) -> dict[str, Any]:
    """A channel-layer message carrying one event of a printer's feed."""
    return {"type": "live.event", "printer_id": printer_id, "event": event}


# -- worker side ---------------------------------------------------------------------


class LivePublisher:
    """Publishes what the worker just wrote, when another process can hear it.

    The worker has one loop and no threads, so the publisher keeps one private event
    loop and runs each send to completion (channels_redis keeps its connections per
    loop). A send is bounded by SEND_TIMEOUT; after a failure messages are dropped for
    PAUSE_AFTER_FAILURE seconds: clients refill from the database on the next message
    or on reconnect, and the printer never waits for Redis.
    """

    def __init__(self, *, enabled: bool | None = None) -> None:
        self.enabled = layer_crosses_processes() if enabled is None else enabled
        self._loop: asyncio.AbstractEventLoop | None = None
        self._down_until = 0.0
        self._logged_at = -LOG_EVERY
        self._state: dict[int, dict[str, Any]] = {}
        #: (job, when read) for progress updates between reads.
        self._job: tuple[Job, float] | None = None
        self.sent = 0
        self.dropped = 0

    def lines(
        self, printer_id: int, rows: Iterable[tuple[int, datetime, str, int]]
    ) -> None:
        """A batch of response lines was stored: (id, time, text, kind) each."""
        if not self.enabled:
            return
        lines = [line_dict(*row) for row in rows]
        if lines:
            self._send(printer_id, {"type": "lines", "lines": lines})

    def status(self, printer_id: int, values: dict[str, Any]) -> None:
        """The printer row's live fields were saved (*values* as written)."""
        if not self.enabled:
            return
        known = self._state.setdefault(printer_id, {})
        changed = {
            name: values[name]
            for name in STATE_FIELDS
            if name in values and known.get(name) != values[name]
        }
        if changed:
            known.update(changed)
            event = {
                "type": "state",
                "state": known.get("state", ""),
                "message": known.get("state_message", ""),
            }
            for name in ("firmware_name", "machine_status", "sd_card"):
                if name in known:
                    event[name] = known[name]
            self._send(printer_id, event)
        if "temperatures" in values:
            event = {"type": "temperatures", "temperatures": values["temperatures"]}
            self._send(printer_id, event)

    def job(
        self, job_id: int | None, *, progress: dict[str, object] | None = None
    ) -> None:
        """A job's row was saved: publish it as stored. *progress*: only these
        counters changed (the worker's progress save), so a row read within
        JOB_REREAD_SECONDS serves with them put in."""
        if not self.enabled or job_id is None:
            return
        now = time.monotonic()
        cached = self._job
        if (
            progress is not None
            and cached is not None
            and cached[0].pk == job_id
            and now - cached[1] < JOB_REREAD_SECONDS
        ):
            job = cached[0]
            for name, value in progress.items():
                setattr(job, name, value)
        else:
            job = (
                Job.objects.filter(pk=job_id)
                .select_related("printer", "analysis")
                .defer("analysis__result")
                .first()
            )
            self._job = None if job is None else (job, now)
        if job is not None:
            self._send(job.printer_id, {"type": "job", "job": job.as_dict()})

    def _send(self, printer_id: int, event: dict[str, Any]) -> None:
        now = time.monotonic()
        if now < self._down_until:
            self.dropped += 1
            return
        layer = get_channel_layer()
        if self._loop is None:
            self._loop = asyncio.new_event_loop()
        send = layer.group_send(group_for(printer_id), message(printer_id, event))
        try:
            self._loop.run_until_complete(asyncio.wait_for(send, SEND_TIMEOUT))
        except Exception as error:  # a broken layer must never stop a print
            self.dropped += 1
            self._down_until = now + PAUSE_AFTER_FAILURE
            if now - self._logged_at >= LOG_EVERY:
                self._logged_at = now
                logger.warning(
                    "live feed unavailable (%r); dropping messages for %.0f s, "
                    "clients catch up from the database",
                    error,
                    PAUSE_AFTER_FAILURE,
                )
            return
        self.sent += 1

    def close(self) -> None:
        if self._loop is not None:
            self._loop.close()
            self._loop = None


_publisher: LivePublisher | None = None


def publisher() -> LivePublisher:
    """The worker process's publisher (created on first use, from the settings)."""
    global _publisher  # one publisher per process
    if _publisher is None:
        _publisher = LivePublisher()
    return _publisher


def reset_publisher(new: LivePublisher | None = None) -> None:
    """Forget the process's publisher (tests, settings changes)."""
    global _publisher
    if _publisher is not None and _publisher is not new:
        _publisher.close()
    _publisher = new


# -- consumer side without Redis: the relay ------------------------------------------


@dataclass
class RelayState:
    """What the relay last saw of a printer, to send only changes."""

    last: int = 0
    state: dict[str, Any] = field(default_factory=dict)
    temperatures: Any = None
    job_id: int | None = None
    job: dict[str, Any] | None = None

    def read(self, printer_id: int, *, first: bool = False) -> list[dict[str, Any]]:
        """Events for what changed since the last read (sync: runs in a DB thread)."""
        events: list[dict[str, Any]] = []
        if first:
            self.last = log_bounds(printer_id)[1]
        else:
            while True:
                lines = lines_after(printer_id, self.last)
                if not lines:
                    break
                self.last = lines[-1]["id"]
                events.append({"type": "lines", "lines": lines})
                if len(lines) < PAGE_LINES:
                    break
        printer = Printer.objects.filter(pk=printer_id).first()
        if printer is None:
            return events
        state = state_of(printer)
        if state != self.state:
            self.state = state
            if not first:
                events.append({"type": "state", **state})
        if printer.temperatures != self.temperatures:
            self.temperatures = printer.temperatures
            if not first:
                events.append(
                    {"type": "temperatures", "temperatures": self.temperatures}
                )
        job = current_job(printer_id)
        if job is None and self.job_id is not None:
            job = Job.objects.filter(pk=self.job_id).first()
        payload = job.as_dict() if job else None
        if payload is not None:
            progress = {k: v for k, v in payload.items() if k != "eta"}
            before = {k: v for k, v in (self.job or {}).items() if k != "eta"}
            if progress != before and not first:
                events.append({"type": "job", "job": payload})
            self.job = payload
        self.job_id = job.pk if job is not None and job.state in ACTIVE_STATES else None
        return events


class Relay:
    """Polls one printer's rows and sends changes into this process's layer."""

    def __init__(self, printer_id: int) -> None:
        self.printer_id = printer_id
        self.users = 0
        self.seen = RelayState()
        self.task: asyncio.Task[None] | None = None
        self.ready = asyncio.Event()

    async def run(self) -> None:
        layer = get_channel_layer()
        read = database_sync_to_async(self.seen.read)
        try:
            await read(self.printer_id, first=True)
        finally:
            self.ready.set()
        group = group_for(self.printer_id)
        while True:
            await asyncio.sleep(RELAY_SECONDS)
            try:
                events = await read(self.printer_id)
            except Exception:
                logger.exception("relay of printer %s could not read", self.printer_id)
                continue
            for event in events:
                await layer.group_send(group, message(self.printer_id, event))


_relays: dict[int, Relay] = {}


def relay_needed() -> bool:
    """Without a cross-process layer nobody publishes: this process must relay."""
    return not layer_crosses_processes()


async def watch(printer_id: int) -> None:
    """A client of this process subscribed to *printer_id*: relay it if needed."""
    if not relay_needed():
        return
    relay = _relays.get(printer_id)
    if relay is None:
        relay = _relays[printer_id] = Relay(printer_id)
        relay.task = asyncio.ensure_future(relay.run())
    relay.users += 1
    await relay.ready.wait()


async def unwatch(printer_id: int) -> None:
    """A client left: stop the printer's relay after its last client."""
    relay = _relays.get(printer_id)
    if relay is None:
        return
    relay.users -= 1
    if relay.users <= 0:
        del _relays[printer_id]
        if relay.task is not None:
            relay.task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await relay.task


def relays_running() -> list[int]:
    """Printers this process relays now (tests and diagnostics)."""
    return sorted(_relays)
