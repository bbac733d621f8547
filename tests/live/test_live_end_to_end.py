"""The live feed against a real runhost: daphne, a worker and a simulator streaming a job.

50 websocket clients each receive every response line in order; one drops mid-job and
resumes with `last=` more than a page back, and with the notice's `/printer/response`
misses and repeats no line. Twice: with the in-process
relay (no Redis) and with Redis (the worker publishes from its own process).
"""

from __future__ import annotations

import asyncio
import json
import urllib.parse
import urllib.request
import uuid
from pathlib import Path
from typing import Any

import pytest
import websockets

from printers.live import PAGE_LINES
from printers.sample_gcode import segments
from tests.conftest import wait_for
from tests.hosts import Host, redis_url

pytestmark = pytest.mark.slow
CLIENTS = 50
JOB_LINES = 3000


@pytest.fixture(params=["relay", pytest.param("redis", marks=pytest.mark.services)])
def host(request: pytest.FixtureRequest, tmp_path: Path) -> Host:
    host = Host(tmp_path, redis=redis_url(db=3) if request.param == "redis" else "")
    # Channel names of parallel runs sharing one Redis must not meet.
    host.env["PRINTHOST_CHANNEL_PREFIX"] = f"printhost-test-{uuid.uuid4().hex[:8]}"
    host.migrate()
    host.add_simulated_printer("p1")
    return host


def db_lines(host: Host, after: int, upto: int) -> list[tuple[int, str]]:
    return host.query(
        "SELECT seq, text FROM printers_responseline WHERE printer_id = "
        "(SELECT id FROM printers_printer WHERE slug = 'p1') "
        f"AND seq > {after} AND seq <= {upto} ORDER BY seq"
    )


def newest(host: Host) -> int:
    return host.query("SELECT COALESCE(MAX(seq), 0) FROM printers_responseline")[0][0]


class Watcher:
    """One websocket client: collects (id, text) of every line it receives."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.lines: list[tuple[int, str]] = []
        self.start = 0
        self.connected = asyncio.Event()
        #: The feed said its catch-up was a page only (the rest read by HTTP).
        self.paged = False

    @property
    def last(self) -> int:
        return self.lines[-1][0] if self.lines else self.start

    async def session(self, query: str, until: Any) -> None:
        # Fifty handshakes at once on a busy machine: the library's 10 s is short
        # (the scenario bounds the whole connecting at 60 s).
        connecting = websockets.connect(
            self.url + query, max_size=None, open_timeout=60
        )
        async with connecting as ws:
            hello = json.loads(await ws.recv())
            assert hello["type"] == "hello", hello
            if not self.connected.is_set():
                self.start = hello["last"]
                self.connected.set()
            while not until(self):
                message = json.loads(await asyncio.wait_for(ws.recv(), 60))
                if message["type"] == "truncated":
                    # A resume further back than a page (a slow reconnect on a
                    # busy machine): the rest is read as the notice says, from
                    # /printer/response. Lines pruned from the log would be lost.
                    assert message.get("paged"), message
                    self.paged = True
                    await asyncio.to_thread(self.read_log, query, message["first"])
                if message["type"] == "lines":
                    self.lines += [(x["id"], x["text"]) for x in message["lines"]]

    def read_log(self, query: str, first: int) -> None:
        """The lines from the last one seen up to *first* (not included), a page of
        `/printer/response` at a time."""
        base = self.url.replace("ws://", "http://").split("/ws/")[0]
        key = urllib.parse.parse_qs(query.lstrip("?"))["apikey"][0]
        while self.last < first - 1:
            address = f"{base}/printer/response/p1?start={self.last}"
            asked = urllib.request.Request(address, headers={"X-Api-Key": key})
            with urllib.request.urlopen(asked, timeout=30) as answer:
                lines = json.load(answer)["data"]["lines"]
            kept = [(x["id"], x["text"]) for x in lines if x["id"] < first]
            assert kept, f"/printer/response gave nothing after {self.last}"
            self.lines += kept


def test_fifty_clients_see_every_line_in_order_and_a_resume_misses_nothing(
    host: Host,
) -> None:
    key = host.add_user("watcher", "viewer")
    job = host.folder / "job.gcode"
    job.write_text(segments(JOB_LINES))
    state = {"final": None}

    def done(watcher: Watcher) -> bool:
        return state["final"] is not None and watcher.last >= state["final"]

    async def scenario(url: str) -> tuple[list[Watcher], Watcher, int]:
        watchers = [Watcher(url) for _ in range(CLIENTS)]
        tasks = [
            asyncio.ensure_future(w.session(f"?apikey={key}", done)) for w in watchers
        ]
        dropper = Watcher(url)
        first = asyncio.ensure_future(
            dropper.session(f"?apikey={key}", lambda w: w.last >= dropper.start + 500)
        )
        await asyncio.wait_for(
            asyncio.gather(*(w.connected.wait() for w in [*watchers, dropper])), 60
        )
        await asyncio.to_thread(host.manage, "add_job", "p1", str(job))
        await asyncio.wait_for(first, 120)
        dropped_at = dropper.last
        # Lines go by while the client is away, more than a page of catch-up (so a
        # slow reconnect is no race): it resumes where it stopped, the feed sends
        # the newest page, and the client reads the rest from /printer/response.
        await asyncio.to_thread(
            wait_for, lambda: newest(host) > dropped_at + PAGE_LINES + 500, 60,
            "lines to pass by",
        )  # fmt: skip
        second = asyncio.ensure_future(
            dropper.session(f"?apikey={key}&last={dropped_at}", done)
        )
        await asyncio.to_thread(
            wait_for,
            lambda: host.query("SELECT state FROM jobs_job")[0][0] == "completed",
            120, "the job to complete",
        )  # fmt: skip
        await asyncio.to_thread(
            wait_for,
            lambda: host.query("SELECT state FROM printers_printer")[0][0] == "waitstart",
            60, "the printer to wait for a clear bed",
        )  # fmt: skip
        state["final"] = newest(host)
        await asyncio.wait_for(asyncio.gather(*tasks, second), 120)
        return watchers, dropper, dropped_at

    with host.running():
        url = f"ws://127.0.0.1:{host.port}/ws/printers/p1/"
        watchers, dropper, dropped_at = asyncio.run(scenario(url))

    final = state["final"]
    everything = db_lines(host, 0, final)
    assert len(everything) > JOB_LINES, "every command of the job is logged"
    for watcher in [*watchers, dropper]:
        expected = [line for line in everything if line[0] > watcher.start]
        got = [line for line in watcher.lines if line[0] <= final]
        assert got == expected, "a client missed, repeated or reordered a line"
    assert dropper.start + 500 <= dropped_at < final - PAGE_LINES - 500
    assert dropper.paged, "the resume came within a page: the paging went untried"
