"""Live clients of a farm: websocket watchers that catch up by last id, and a steady
API load; both in one asyncio loop on a thread of their own, beside the harness.

A `Watcher` follows one printer's log (`/ws/printers/<slug>/`) and reconnects
with `last=<id>` whenever it is dropped, as a browser does. An `ApiLoad` sends
GET requests at a fixed rate and keeps each one's latency.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import httpx
import websockets

if TYPE_CHECKING:
    from collections.abc import Coroutine


#: The clients' thread runs this much nicer than the farm's processes.
CLIENT_NICE = 10


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

    async def run(self, key: str, stop: asyncio.Event) -> None:
        while not self.done() and not stop.is_set():
            query = f"?apikey={key}" + (f"&last={self.last}" if self.start else "")
            try:
                async with websockets.connect(self.url + query, max_size=None) as ws:
                    hello = json.loads(await ws.recv())
                    if self.start is None:
                        self.start = hello["last"]
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


@dataclass
class ApiLoad:
    """GET *paths* in turn at *rate* requests a second; latencies in seconds."""

    base_url: str
    key: str
    paths: list[str]
    rate: float
    latencies: list[float] = field(default_factory=list)
    errors: int = 0
    #: How late each request left against its schedule (the client's own loop
    #: busy, not the server): what the latencies include of the client.
    lags: list[float] = field(default_factory=list)

    async def run(self, stop: asyncio.Event) -> None:
        headers = {"X-Api-Key": self.key}
        limits = httpx.Limits(max_connections=20)
        async with httpx.AsyncClient(
            base_url=self.base_url, headers=headers, timeout=30, limits=limits
        ) as client:
            tasks = set()
            start, n = time.monotonic(), 0
            while not stop.is_set():
                due = start + n / self.rate
                await asyncio.sleep(max(0.0, due - time.monotonic()))
                self.lags.append(time.monotonic() - due)
                task = asyncio.ensure_future(
                    self._get(client, self.paths[n % len(self.paths)])
                )
                tasks.add(task)
                task.add_done_callback(tasks.discard)
                n += 1
            await asyncio.gather(*tasks, return_exceptions=True)

    async def _get(self, client: httpx.AsyncClient, path: str) -> None:
        sent = time.monotonic()
        try:
            response = await client.get(path)
        except httpx.HTTPError:
            self.errors += 1
            return
        if response.status_code != 200:
            self.errors += 1
            return
        self.latencies.append(time.monotonic() - sent)

    def p95(self) -> float | None:
        if not self.latencies:
            return None
        ordered = sorted(self.latencies)
        return ordered[min(len(ordered) - 1, int(0.95 * len(ordered)))]


class Crowd:
    """Watchers (and an API load) running on a thread until `finish`."""

    def __init__(
        self, watchers: list[Watcher], key: str, load: ApiLoad | None = None
    ) -> None:
        self.watchers = watchers
        self.key = key
        self.load = load
        self._loop = asyncio.new_event_loop()
        self._stop: asyncio.Event | None = None
        self._stop_load: asyncio.Event | None = None
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._ready = threading.Event()

    def start(self) -> None:
        self._thread.start()
        self._ready.wait(10)

    def connected(self) -> bool:
        return all(w.start is not None for w in self.watchers)

    def _run(self) -> None:
        # The clients stand for browsers and hosts on other computers: on this one
        # they must not take the printers' CPU (the thread's own niceness).
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), CLIENT_NICE)
        asyncio.set_event_loop(self._loop)
        self._loop.run_until_complete(self._main())

    async def _main(self) -> None:
        self._stop, self._stop_load = asyncio.Event(), asyncio.Event()
        self._ready.set()
        jobs: list[Coroutine] = [w.run(self.key, self._stop) for w in self.watchers]
        if self.load is not None:
            jobs.append(self.load.run(self._stop_load))
        await asyncio.gather(*jobs)

    def stop_load(self) -> None:
        """Stop the API load (its requests in flight end); the watchers go on."""
        if self._stop_load is not None:
            self._loop.call_soon_threadsafe(self._stop_load.set)

    def finish(self, finals: dict[str, int], timeout: float) -> None:
        """Let each watcher end once it has its printer's line *finals[slug]*; stop
        everything after *timeout* seconds."""
        for watcher in self.watchers:
            watcher.final = finals[watcher.slug]
        self._thread.join(timeout)
        if self._thread.is_alive():
            self.stop()

    def stop(self) -> None:
        self.stop_load()
        if self._stop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(30)
        with contextlib.suppress(RuntimeError):
            self._loop.close()
