"""Live clients of a farm: websocket watchers that catch up by last id, and a steady
API load; plain asyncio, run by `crowd.Crowd` in processes of their own (or awaited
directly by a test's own loop).

A `Watcher` follows one printer's log (`/ws/printers/<slug>/`) and reconnects
with `last=<id>` whenever it is dropped, as a browser does. An `ApiLoad` sends
GET requests at a fixed rate and keeps each one's latency, how late it left and
how many it sent in how long (the rate it really reached).
"""

from __future__ import annotations

import asyncio
import json
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import aiohttp
import websockets

if TYPE_CHECKING:
    from collections.abc import Callable


@dataclass
class Watcher:
    """One websocket client of one printer's log."""

    url: str
    slug: str
    lines: list[tuple[int, str]] = field(default_factory=list)
    start: int | None = None
    reconnects: int = 0
    final: int | None = None

    @property
    def last(self) -> int:
        return self.lines[-1][0] if self.lines else (self.start or 0)

    def done(self) -> bool:
        return self.final is not None and self.last >= self.final

    async def run(
        self,
        key: str,
        stop: asyncio.Event,
        started: Callable[[], None] | None = None,
    ) -> None:
        """Follow the log until `done()` or *stop*; *started* is called once, when
        the first hello gave `start`."""
        while not self.done() and not stop.is_set():
            query = f"?apikey={key}" + (f"&last={self.last}" if self.start else "")
            try:
                async with websockets.connect(self.url + query, max_size=None) as ws:
                    hello = json.loads(await ws.recv())
                    if self.start is None:
                        self.start = hello["last"]
                        if started is not None:
                            started()
                    await self._receive(ws, stop)
            except (websockets.ConnectionClosed, OSError):
                self.reconnects += 1
                await asyncio.sleep(0.2)  # a client's reconnect delay

    async def _receive(
        self, ws: websockets.ClientConnection, stop: asyncio.Event
    ) -> None:
        while not self.done() and not stop.is_set():
            try:
                raw = await asyncio.wait_for(ws.recv(), 1.0)
            except TimeoutError:
                continue
            message = json.loads(raw)
            if message["type"] == "lines":
                self.lines += [(x["id"], x["text"]) for x in message["lines"]]


#: Connections the API load keeps open at most (requests beyond wait their turn).
API_CONNECTIONS = 20


@dataclass
class ApiLoad:
    """GET *paths* in turn at *rate* requests a second; latencies in seconds.

    The schedule is kept whatever the server does: a request is issued on time and,
    when all `API_CONNECTIONS` are busy, waits its turn in a plain FIFO here. (Left
    to httpx's pool, thousands of waiting requests made every pool event scan them
    all: the load's loop used a whole core and fell minutes behind its schedule.)
    At the stop, requests still waiting are dropped: they were never sent.

    aiohttp, not httpx: at 50 requests a second, each costs this process about
    1.3 ms of CPU where httpx took 4.5 (measured against an instant server), and
    a process at nice 10 on a busy machine cannot count on a fifth of a core.
    """

    base_url: str
    key: str
    paths: list[str]
    rate: float
    #: Each sent request's time on its connection, sent to answered.
    latencies: list[float] = field(default_factory=list)
    errors: int = 0
    #: How late each request was issued against its schedule (the client's own
    #: loop busy, not the server).
    lags: list[float] = field(default_factory=list)
    #: Requests issued on schedule, and sent (given a connection) before the stop;
    #: the seconds from the first one's due time to the stop. `sent / seconds` is
    #: the rate the load really reached beside the *rate* it was asked for.
    issued: int = 0
    sent: int = 0
    seconds: float = 0.0

    async def run(self, stop: asyncio.Event) -> None:
        turns = asyncio.Semaphore(API_CONNECTIONS)
        async with aiohttp.ClientSession(
            self.base_url,
            headers={"X-Api-Key": self.key},
            timeout=aiohttp.ClientTimeout(total=30),
            connector=aiohttp.TCPConnector(limit=API_CONNECTIONS),
        ) as client:
            tasks = set()
            start = time.monotonic()
            while not stop.is_set():
                due = start + self.issued / self.rate
                await asyncio.sleep(max(0.0, due - time.monotonic()))
                self.lags.append(time.monotonic() - due)
                path = self.paths[self.issued % len(self.paths)]
                task = asyncio.ensure_future(self._get(client, turns, stop, path))
                tasks.add(task)
                task.add_done_callback(tasks.discard)
                self.issued += 1
            self.seconds = time.monotonic() - start
            await asyncio.gather(*tasks, return_exceptions=True)

    async def _get(
        self,
        client: aiohttp.ClientSession,
        turns: asyncio.Semaphore,
        stop: asyncio.Event,
        path: str,
    ) -> None:
        async with turns:
            if stop.is_set():
                return  # still waiting at the stop: never sent
            self.sent += 1
            sent = time.monotonic()
            try:
                async with client.get(path) as response:
                    await response.read()
            except (aiohttp.ClientError, TimeoutError):
                self.errors += 1
                return
            if response.status != 200:
                self.errors += 1
                return
            self.latencies.append(time.monotonic() - sent)

    def achieved_rate(self) -> float | None:
        """Requests sent a second, over the time the load ran (None before it ran)."""
        return self.sent / self.seconds if self.seconds > 0 else None

    def p95(self) -> float | None:
        if not self.latencies:
            return None
        ordered = sorted(self.latencies)
        return ordered[min(len(ordered) - 1, int(0.95 * len(ordered)))]
