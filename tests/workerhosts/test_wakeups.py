"""A worker is woken by what is written for its printer (printers/worker/wakeup.py:
PostgreSQL's NOTIFY, or on SQLite its doorbell, printers/doorbell.py), so it reads
the database rarely and still answers at once.

The worker's fallback poll is set to two minutes: only a notification (or a ring)
can start the job or answer the request within the tests' bounds.
"""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from printers.sample_gcode import segments
from printers.worker.wakeup import Wakeups, channel_for
from tests.conftest import wait_for
from tests.hosts import Host, postgres_url

pytestmark = [pytest.mark.slow, pytest.mark.services]


@pytest.fixture(params=["postgres", "sqlite"])
def host(tmp_path: Path, request: pytest.FixtureRequest) -> Host:
    host = Host(tmp_path, postgres_url() if request.param == "postgres" else "")
    host.migrate()
    host.env["PRINTHOST_FALLBACK_POLL_SECONDS"] = "120"
    host.add_simulated_printer("p1", sim_args="--time-scale 0")
    return host


def _state(host: Host) -> str:
    return host.query("SELECT state FROM printers_printer")[0][0]


def test_a_queued_job_and_a_command_wake_a_worker_that_polls_every_two_minutes(
    host: Host, tmp_path: Path
):
    key = host.add_user("op", "operator")
    (tmp_path / "part.gcode").write_text(segments(50))
    (printer_id,) = host.query("SELECT id FROM printers_printer")[0]
    bell = tmp_path / "doorbells" / f"printer-{printer_id}"
    with host.running():
        wait_for(lambda: _state(host) == "idle", 60, "the printer to be idle")
        # On SQLite the worker waits on its doorbell (PostgreSQL: its LISTEN).
        assert bell.is_fifo() == (not host.database_url)
        host.manage("add_job", "p1", str(tmp_path / "part.gcode"))
        wait_for(
            lambda: host.query("SELECT state FROM jobs_job")[0][0] == "completed",
            30, "the job to start and complete",
        )  # fmt: skip
        with httpx.Client(base_url=host.url, headers={"X-Api-Key": key}) as client:
            wait_for(lambda: _state(host) == "waitstart", 10, "waitstart")
            response = client.post("/printer/bedclear/p1")
            assert response.status_code == 200, response.text
            wait_for(lambda: _state(host) == "idle", 15, "the bed clear to be taken")
    assert not bell.exists(), "the stopped worker left its doorbell"


def test_the_triggers_notify_only_the_printer_written_for(tmp_path: Path):
    """The migration's triggers, seen from a plain psycopg connection: a request
    and a queued job notify their printer's channel, at commit."""
    import psycopg

    host = Host(tmp_path, postgres_url())
    host.migrate()
    host.add_simulated_printer("p1")
    host.add_simulated_printer("p2")
    ids = dict(host.query("SELECT slug, id FROM printers_printer"))
    (tmp_path / "part.gcode").write_text(segments(5))
    with psycopg.connect(host.database_url, autocommit=True) as listener:
        for slug in ("p1", "p2"):
            listener.execute(f"LISTEN {channel_for(ids[slug])}")
        host.manage("add_job", "p2", str(tmp_path / "part.gcode"))
        heard = [n.channel for n in listener.notifies(timeout=5, stop_after=1)]
        assert heard == [channel_for(ids["p2"])]
        host.shell(
            "from printers.models import Printer, QueuedCommand; "
            "QueuedCommand.objects.create(printer=Printer.objects.get(slug='p1'), "
            "text='M105')"
        )
        heard = [n.channel for n in listener.notifies(timeout=5, stop_after=1)]
        assert heard == [channel_for(ids["p1"])]


def test_without_postgresql_there_is_nothing_to_wait_on(db):
    wakeups = Wakeups(1)
    assert wakeups.fileno() is None
    assert not wakeups.listening
    assert wakeups.take(readable=False) is False
