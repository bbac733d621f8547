"""A worker host's metrics server under misuse: an idle or a dripping connection does
not hold off the scrapes, a database error tells an unauthenticated caller nothing
of the database, and it answers other computers only with the scrape token
(`manage.py serve_metrics`)."""

from __future__ import annotations

import os
import socket
import threading
from unittest import mock

import pytest
from django.core.management import CommandError, call_command
from django.db import OperationalError

from printhost.management.commands.serve_metrics import REQUEST_SECONDS, answer
from printhost.metrics_access import bind_refusal
from tests.hosts import Host
from tests.ops.test_metrics_end_to_end import serve_metrics

pytestmark = pytest.mark.django_db


def test_a_database_error_answers_503_without_the_databases_details() -> None:
    secret = 'connection to server at "10.0.0.5", port 5432 failed: role "farm"'
    with mock.patch(
        "printhost.management.commands.serve_metrics.header_refusal",
        side_effect=OperationalError(secret),
    ):
        status, _, body = answer(
            {"PATH_INFO": "/metrics", "REQUEST_METHOD": "GET",
             "HTTP_AUTHORIZATION": "Bearer ph_bogus"},
            "rack1",
        )  # fmt: skip
    assert status.startswith("503")
    assert b"not reachable" in body
    assert b"10.0.0.5" not in body and b"farm" not in body


@pytest.mark.slow
def test_an_idle_connection_does_not_hold_off_a_scrape(tmp_path) -> None:
    import httpx

    host = Host(tmp_path)
    host.migrate()
    host.shell("from printers.hosts import WorkerHost; "
               "WorkerHost.objects.create(name='rack1')")  # fmt: skip
    served = serve_metrics(host, "rack1")
    try:
        address, port = served.address.rsplit(":", 1)
        with socket.create_connection((address, int(port))) as idle:
            idle.sendall(b"GET /metr")  # and nothing more
            answer = httpx.get(served.url, timeout=15)
        assert answer.status_code == 401  # answered, not stuck behind the idle one
    finally:
        served.stop()


@pytest.mark.slow
def test_a_request_dripped_a_byte_a_second_is_dropped_and_the_scrape_answered(
    tmp_path,
) -> None:
    """Each byte within the 2 s a read may wait, but the request never whole: it
    is dropped at REQUEST_SECONDS, and the scrape behind it answered."""
    import httpx

    host = Host(tmp_path)
    host.migrate()
    host.shell("from printers.hosts import WorkerHost; "
               "WorkerHost.objects.create(name='rack1')")  # fmt: skip
    served = serve_metrics(host, "rack1")
    stop = threading.Event()

    def drip(connection: socket.socket) -> None:
        for byte in b"GET /metrics HTTP/1.1\r\nHost: x\r\nX-Slow: " + b"a" * 1000:
            if stop.wait(1.0):  # the drip's pace, not a wait for anything
                return
            try:
                connection.sendall(bytes([byte]))
            except OSError:
                return  # dropped by the server

    try:
        address, port = served.address.rsplit(":", 1)
        with socket.create_connection((address, int(port))) as slow:
            dripping = threading.Thread(target=drip, args=(slow,), daemon=True)
            dripping.start()
            answer = httpx.get(served.url, timeout=REQUEST_SECONDS + 10)
            assert answer.status_code == 401  # answered, not stuck behind the drip
            stop.set()
            dripping.join(timeout=5)
    finally:
        stop.set()
        served.stop()


@pytest.mark.parametrize("bind", ["0.0.0.0", "::", "192.168.1.20", "rack1.lan"])
def test_metrics_for_other_computers_need_the_scrape_token(
    bind: str, settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    # runhost in this process: whatever of the environment it sets is put back.
    for name in ("PRINTHOST_DATA_DIR", "PRINTHOST_WORKER_HOST"):
        monkeypatch.setenv(name, os.environ.get(name, ""))
    settings.PRINTHOST_METRICS_TOKEN = ""
    assert "PRINTHOST_METRICS_TOKEN" in bind_refusal(bind)
    with pytest.raises(CommandError, match="PRINTHOST_METRICS_TOKEN"):
        call_command("serve_metrics", "--worker-host", "rack1", "--bind", bind)
    with pytest.raises(CommandError, match=r"--metrics-bind: .*METRICS_TOKEN"):
        call_command(
            "runhost", "--no-web", "--worker-host", "rack1", "--metrics-port", "9108",
            "--metrics-bind", bind,
        )  # fmt: skip
    settings.PRINTHOST_METRICS_TOKEN = "a-long-scrape-token"
    assert bind_refusal(bind) == ""


@pytest.mark.parametrize("bind", ["127.0.0.1", "::1", "[::1]", "localhost"])
def test_metrics_on_this_computer_only_need_no_token(bind: str, settings) -> None:
    settings.PRINTHOST_METRICS_TOKEN = ""
    assert bind_refusal(bind) == ""
