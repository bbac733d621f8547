"""The Redis channel layer, made to ride out a Redis restart.

channels_redis raises when Redis goes away; a consumer whose `receive` raises is
closed (1011), and a client reconnecting while Redis is still away is refused,
again and again. Redis also forgets every group when it restarts without
persistence. So here:

- `receive` waits out a Redis that is away (retrying with a doubling delay up to
  2 s) instead of raising; when Redis answers again it first joins the channel's
  groups again (it remembers them per channel), then receives;
- `group_add` and `group_discard` that fail are logged and dropped (`receive`
  joins again). `send` and `group_send` still raise: the worker's publisher
  (`printers/broadcast.py`) counts on it to stop trying for a while. The live feed
  is lossy by design: every client re-reads the response log past its last id
  every few seconds (`printers/consumers.py`), so a lost message costs a few
  seconds, never a line.
"""

from __future__ import annotations

import asyncio
import logging
from collections import defaultdict
from typing import Any

from channels_redis.core import RedisChannelLayer
from redis.exceptions import RedisError

logger = logging.getLogger("printhost.live")

UNREACHABLE = (RedisError, OSError)
RETRY_FIRST = 0.1
RETRY_CAP = 2.0


class ResilientRedisChannelLayer(RedisChannelLayer):
    """RedisChannelLayer that waits out a Redis restart instead of failing."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.memberships: defaultdict[str, set[str]] = defaultdict(set)
        self.away = False

    def _went_away(self, what: str, error: BaseException) -> None:
        if not self.away:
            logger.warning("Redis unavailable (%s: %r); waiting for it", what, error)
        self.away = True

    async def receive(self, channel: str) -> dict[str, Any]:
        delay = RETRY_FIRST
        rejoin = False
        while True:
            try:
                if rejoin:
                    for group in list(self.memberships.get(channel, ())):
                        await super().group_add(group, channel)
                    rejoin = False
                    if self.away:
                        logger.info("Redis is back; groups joined again")
                        self.away = False
                return await super().receive(channel)
            except UNREACHABLE as error:
                self._went_away("receive", error)
                rejoin = True
                await asyncio.sleep(delay)
                delay = min(delay * 2, RETRY_CAP)

    async def group_add(self, group: str, channel: str) -> None:
        self.memberships[channel].add(group)
        try:
            await super().group_add(group, channel)
        except UNREACHABLE as error:
            self._went_away("group_add", error)  # joined again by receive

    async def group_discard(self, group: str, channel: str) -> None:
        members = self.memberships.get(channel)
        if members is not None:
            members.discard(group)
            if not members:
                del self.memberships[channel]
        try:
            await super().group_discard(group, channel)
        except UNREACHABLE as error:
            self._went_away("group_discard", error)
