"""The web server on real PostgreSQL keeps a pool of connections: a burst of API
requests, each answered on a thread of its own, opens a few database sessions, not
one a request; and its queries run without PostgreSQL's JIT."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING

import httpx
import pytest

from printhost.serve import WEB_POOL_SIZE
from tests.hosts import Host, postgres_url

if TYPE_CHECKING:
    from pathlib import Path

pytestmark = [pytest.mark.slow, pytest.mark.services]

REQUESTS = 60


def _sessions(host: Host) -> int:
    """Sessions PostgreSQL has opened on the host's database so far."""
    name = host.database_url.rsplit("/", 1)[1]
    return host.query(
        f"SELECT sessions FROM pg_stat_database WHERE datname = '{name}'"
    )[0][0]


def test_a_burst_of_requests_shares_a_few_pooled_connections(tmp_path: Path):
    host = Host(tmp_path, postgres_url())
    host.migrate()
    key = host.add_user("viewer", "viewer")
    with host.running():
        headers = {"X-Api-Key": key}
        with httpx.Client(base_url=host.url, headers=headers, timeout=30) as client:
            assert client.get("/printer/list").status_code == 200  # the pool opens
            before = _sessions(host)

            def ask(_: int) -> int:
                return client.get("/printer/list").status_code

            with ThreadPoolExecutor(max_workers=8) as pool:
                answers = list(pool.map(ask, range(REQUESTS)))
            after = client.get("/printer/list")  # still answering
            opened = _sessions(host) - before
    assert answers == [200] * REQUESTS
    assert after.status_code == 200
    # One session is the test's own query; without the pool each request opened one.
    assert opened <= WEB_POOL_SIZE + 1, f"{opened} sessions for {REQUESTS} requests"


def test_printhost_connections_run_without_jit(tmp_path: Path):
    host = Host(tmp_path, postgres_url())
    host.migrate()
    answer = host.shell(
        "from django.db import connection\n"
        "with connection.cursor() as cursor:\n"
        "    cursor.execute('SHOW jit')\n"
        "    print(cursor.fetchone()[0])"
    )
    assert answer.splitlines()[-1] == "off"
