"""Celery's queue lengths for /metrics: messages waiting in the broker, per queue.

Read the way each broker printhost configures keeps them, with no Celery
connection (a scrape must not wait on a broker's reconnect loop):

- Redis (`REDIS_URL`, or a `redis://` / `rediss://` PRINTHOST_CELERY_BROKER): kombu
  keeps a queue as a list named after it, plus one list per priority step
  (`<queue>\\x06\\x16<step>`); the length is the sum of their `LLEN`s, asked in one
  pipeline with a 1 s socket timeout.
- kombu's filesystem transport (no Redis, `make run`): one file per message,
  `<time>_<uuid>.<queue>.msg`, in the queue folder; the length is the number of
  such files.

Another broker gives no length. `printhost_celery_broker_up` is 0 when the broker
could not be read (the lengths are then left out, not reported as 0).
"""

from __future__ import annotations

import logging
import os
from typing import TYPE_CHECKING

import redis
from django.conf import settings
from prometheus_client.core import GaugeMetricFamily

if TYPE_CHECKING:
    from collections.abc import Iterator

    from prometheus_client import Metric

logger = logging.getLogger("printhost.metrics")

#: kombu's Redis transport: the separator and priority steps of its queue lists.
REDIS_PRIORITY_SEP = "\x06\x16"
REDIS_PRIORITY_STEPS = (3, 6, 9)
#: Seconds a scrape waits for Redis.
REDIS_TIMEOUT = 1.0


def queue_names() -> list[str]:
    """The queues settings name: the default queue and any routed to."""
    names = [settings.CELERY_TASK_DEFAULT_QUEUE]
    routes = getattr(settings, "CELERY_TASK_ROUTES", None) or {}
    if isinstance(routes, dict):
        for route in routes.values():
            queue = route.get("queue") if isinstance(route, dict) else None
            if isinstance(queue, str) and queue not in names:
                names.append(queue)
    return names


def redis_lengths(url: str, queues: list[str]) -> dict[str, int]:
    """LLEN of each queue's lists (every priority step), summed per queue."""
    client = redis.Redis.from_url(
        url, socket_timeout=REDIS_TIMEOUT, socket_connect_timeout=REDIS_TIMEOUT
    )
    try:
        pipe = client.pipeline(transaction=False)
        keys = {
            queue: [
                queue,
                *(
                    f"{queue}{REDIS_PRIORITY_SEP}{step}"
                    for step in REDIS_PRIORITY_STEPS
                ),
            ]
            for queue in queues
        }
        for names in keys.values():
            for key in names:
                pipe.llen(key)
        answers = iter(pipe.execute())
        return {
            queue: sum(next(answers) for _ in names) for queue, names in keys.items()
        }
    finally:
        client.close()


def filesystem_lengths(folder: str, queues: list[str]) -> dict[str, int]:
    """Message files per queue in kombu's filesystem transport's folder."""
    counts = dict.fromkeys(queues, 0)
    for entry in os.scandir(folder):
        # kombu matches a message to its queue the same way: after the first dot.
        queue = entry.name.partition(".")[2].removesuffix(".msg")
        if entry.name.endswith(".msg") and queue in counts:
            counts[queue] += 1
    return counts


def queue_lengths() -> dict[str, int] | None:
    """Messages waiting per queue; {} for a broker we cannot read; None if it is down."""
    broker = settings.CELERY_BROKER_URL
    queues = queue_names()
    try:
        if broker.startswith(("redis://", "rediss://", "unix://")):
            return redis_lengths(broker, queues)
        if broker.startswith("filesystem://"):
            folder = settings.CELERY_BROKER_TRANSPORT_OPTIONS["data_folder_in"]
            return filesystem_lengths(folder, queues)
    except (OSError, redis.RedisError) as error:
        logger.warning("Celery queue lengths: the broker is not readable (%s)", error)
        return None
    return {}


def queue_families() -> Iterator[Metric]:
    """printhost_celery_queue_length{queue} and printhost_celery_broker_up."""
    lengths = queue_lengths()
    up = GaugeMetricFamily(
        "printhost_celery_broker_up",
        "1 when the Celery broker's queues could be read, 0 when not",
    )
    length = GaugeMetricFamily(
        "printhost_celery_queue_length",
        "Celery messages waiting in the broker (tasks not taken by a worker yet)",
        labels=["queue"],
    )
    up.add_metric([], 0.0 if lengths is None else 1.0)
    for queue, count in sorted((lengths or {}).items()):
        length.add_metric([queue], float(count))
    yield up
    yield length
