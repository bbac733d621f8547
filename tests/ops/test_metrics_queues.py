"""Celery queue lengths: messages put by kombu itself, counted the broker's way."""

from __future__ import annotations

import uuid

import pytest
from kombu import Connection
from kombu.transport import filesystem, virtual

from printhost import metrics_queues
from tests.hosts import redis_url


def put(
    url: str, queue: str, count: int, options: dict | None = None, **priority: int
) -> None:
    """*count* messages on *queue* through kombu, as Celery's producer sends them."""
    with Connection(url, transport_options=options or {}) as connection:
        simple = connection.SimpleQueue(queue)
        for n in range(count):
            simple.put({"n": n}, **priority)
        simple.close()


def families() -> dict:
    return {
        (sample.name, sample.labels.get("queue", "")): sample.value
        for family in metrics_queues.queue_families()
        for sample in family.samples
    }


def test_the_filesystem_broker_counts_its_message_files(
    settings, tmp_path, monkeypatch
):
    folder = tmp_path / "queue"
    folder.mkdir()
    options = {"data_folder_in": str(folder), "data_folder_out": str(folder)}
    # kombu writes its exchange files to ./control: keep them in this test's folder.
    monkeypatch.chdir(tmp_path)
    # ...and remembers, process-wide, which bindings it declared: one declared by
    # an earlier test (an analysis sent through the filesystem broker) would skip
    # this folder's exchange file, and the messages would go to no queue.
    monkeypatch.setattr(filesystem.Transport, "global_state", virtual.BrokerState())
    settings.CELERY_BROKER_URL = "filesystem://"
    settings.CELERY_BROKER_TRANSPORT_OPTIONS = options
    settings.CELERY_TASK_DEFAULT_QUEUE = "printhost"
    put("filesystem://", "printhost", 3, options)
    put("filesystem://", "elsewhere", 2, options)
    found = families()
    assert found[("printhost_celery_queue_length", "printhost")] == 3
    assert ("printhost_celery_queue_length", "elsewhere") not in found
    assert found[("printhost_celery_broker_up", "")] == 1


@pytest.mark.services
def test_redis_counts_every_priority_list_of_the_queue(settings):
    url = redis_url(db=3)
    queue = f"metrics-test-{uuid.uuid4().hex[:8]}"
    settings.CELERY_BROKER_URL = url
    settings.CELERY_TASK_DEFAULT_QUEUE = queue
    try:
        put(url, queue, 2)
        put(url, queue, 3, priority=9)
        found = families()
        assert found[("printhost_celery_queue_length", queue)] == 5
        assert found[("printhost_celery_broker_up", "")] == 1
    finally:
        import redis

        client = redis.Redis.from_url(url)
        client.delete(queue, *(f"{queue}\x06\x16{step}" for step in (3, 6, 9)))
        client.close()


def test_a_broker_that_is_away_reads_as_down_not_as_empty(settings):
    settings.CELERY_BROKER_URL = "redis://127.0.0.1:9/0"  # discard port: refused
    found = families()
    assert found[("printhost_celery_broker_up", "")] == 0
    assert not [key for key in found if key[0] == "printhost_celery_queue_length"]
