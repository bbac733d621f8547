"""A worker host's metrics server under misuse: an idle connection does not hold off
the scrapes, and a database error tells an unauthenticated caller nothing of the
database (`manage.py serve_metrics`)."""

from __future__ import annotations

import socket
from unittest import mock

import pytest
from django.db import OperationalError

from printhost.management.commands.serve_metrics import answer
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
