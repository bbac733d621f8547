"""The worker's publisher: what it sends after each write, and that Redis can't stall it."""

from __future__ import annotations

import asyncio
import socket
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime

import pytest
from channels.layers import channel_layers, get_channel_layer

from printers import broadcast, live
from printers.models import Printer


@pytest.fixture(autouse=True)
def fresh_layer() -> Iterator[None]:
    channel_layers.backends.clear()
    broadcast.reset_publisher()
    yield
    broadcast.reset_publisher()
    channel_layers.backends.clear()


def listen(publisher: broadcast.LivePublisher, printer_id: int) -> Callable[[], dict]:
    """Join the printer's group on the publisher's loop; returns a receive function."""
    layer = get_channel_layer()
    publisher._loop = publisher._loop or asyncio.new_event_loop()
    run = publisher._loop.run_until_complete
    channel = run(layer.new_channel())
    run(layer.group_add(live.group_for(printer_id), channel))
    return lambda: run(layer.receive(channel))


def test_a_stored_batch_is_published_with_ids_times_and_kinds() -> None:
    publisher = broadcast.LivePublisher(enabled=True)
    receive = listen(publisher, 7)
    when = datetime(2026, 1, 2, 3, 4, 5, tzinfo=UTC)
    publisher.lines(7, [(41, when, "ok", 2), (42, when, "echo:busy", 4)])
    message = receive()
    assert message["printer_id"] == 7
    assert message["event"] == {
        "type": "lines",
        "lines": [
            {"id": 41, "time": "2026-01-02T03:04:05+00:00", "text": "ok", "type": 2},
            {
                "id": 42,
                "time": "2026-01-02T03:04:05+00:00",
                "text": "echo:busy",
                "type": 4,
            },
        ],
    }


def test_state_is_published_when_it_changes_and_temperatures_on_each_save() -> None:
    publisher = broadcast.LivePublisher(enabled=True)
    receive = listen(publisher, 3)
    saved = {
        "state": "printing",
        "state_message": "",
        "temperatures": {"T0": [200, 210]},
    }
    publisher.status(3, saved)
    assert receive()["event"] == {"type": "state", "state": "printing", "message": ""}
    assert receive()["event"]["temperatures"] == {"T0": [200, 210]}
    publisher.status(3, {"state": "printing", "state_message": ""})
    publisher.status(3, {"state": "paused", "state_message": "by op"})
    assert receive()["event"] == {
        "type": "state",
        "state": "paused",
        "message": "by op",
    }


@pytest.mark.django_db
def test_job_progress_is_published_as_stored(
    make_printer: Callable[..., Printer], make_job: Callable[..., object]
) -> None:
    printer = make_printer()
    job = make_job(printer, "G28\nG1 X1\n")
    job.lines_acked = 1
    job.save()
    publisher = broadcast.LivePublisher(enabled=True)
    receive = listen(publisher, printer.pk)
    publisher.job(job.pk)
    event = receive()["event"]
    assert event["type"] == "job"
    assert (event["job"]["id"], event["job"]["lines_acked"]) == (job.pk, 1)
    assert event["job"]["lines"] == 2


@pytest.mark.django_db
def test_progress_between_reads_comes_from_the_worker_and_anything_else_rereads(
    make_printer: Callable[..., Printer],
    make_job: Callable[..., object],
    django_assert_num_queries: Callable[..., object],
) -> None:
    printer = make_printer()
    job = make_job(printer, "G28\nG1 X1\nG1 X2\n")
    publisher = broadcast.LivePublisher(enabled=True)
    receive = listen(publisher, printer.pk)
    publisher.job(job.pk, progress={"lines_acked": 1})
    assert receive()["event"]["job"]["lines_acked"] == 0  # the first one reads the row
    type(job).objects.filter(pk=job.pk).update(lines_acked=2, message="a note")
    with django_assert_num_queries(0):
        publisher.job(job.pk, progress={"lines_acked": 2, "lines_sent": 3})
    event = receive()["event"]["job"]
    assert (event["lines_acked"], event["lines_sent"], event["message"]) == (2, 3, "")
    publisher.job(job.pk)  # not a progress save: the row as stored
    assert receive()["event"]["job"]["message"] == "a note"


def test_nothing_is_published_without_a_cross_process_layer() -> None:
    assert broadcast.publisher().enabled is False
    broadcast.publisher().lines(1, [(1, datetime.now(UTC), "ok", 2)])
    assert broadcast.publisher().sent == 0


def test_an_unreachable_redis_never_stalls_the_worker(settings: object) -> None:
    with socket.socket() as closed:
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]
    settings.CHANNEL_LAYERS = {  # type: ignore[attr-defined]
        "default": {
            "BACKEND": "channels_redis.core.RedisChannelLayer",
            "CONFIG": {"hosts": [f"redis://127.0.0.1:{port}/0"]},
        }
    }
    channel_layers.backends.clear()
    publisher = broadcast.publisher()
    assert publisher.enabled
    started = time.monotonic()
    for seq in range(200):
        publisher.lines(1, [(seq, datetime.now(UTC), "ok", 2)])
    assert time.monotonic() - started < broadcast.SEND_TIMEOUT + 1.0
    assert publisher.sent == 0
    assert publisher.dropped == 200
