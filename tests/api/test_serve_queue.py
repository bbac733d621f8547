"""printhost.serve's input queue: request bodies past 1 MB wait on disk, in order."""

from __future__ import annotations

import asyncio

from printhost.serve import HELD_BYTES, SpooledBodyQueue


def spooled_queue() -> SpooledBodyQueue:
    queue: asyncio.Queue = asyncio.Queue()
    queue.__class__ = SpooledBodyQueue
    queue.become_spooled()
    return queue  # type: ignore[return-value]


def test_bodies_come_back_whole_and_in_order_while_memory_holds_at_most_1_mb():
    queue = spooled_queue()
    chunks = [bytes([i % 251]) * 65536 for i in range(64)]  # 4 MiB in all
    for i, chunk in enumerate(chunks):
        more = i < len(chunks) - 1
        queue.put_nowait({"type": "http.request", "body": chunk, "more_body": more})
        assert queue._held <= HELD_BYTES
    assert queue._spool is not None, "nothing went to disk"

    async def drain() -> list[dict]:
        return [await queue.get() for _ in chunks]

    got = asyncio.run(drain())
    assert [m["body"] for m in got] == chunks
    assert [m["more_body"] for m in got] == [True] * 63 + [False]
    assert all("spooled" not in m for m in got)
    assert queue._spool is None, "the spool file outlived the request"


def test_other_messages_pass_through_untouched():
    queue = spooled_queue()
    queue.put_nowait({"type": "http.disconnect"})
    assert queue.get_nowait() == {"type": "http.disconnect"}
