"""A worker host whose clock is off stamps its prints and log by the database's
clock all the same (printers/dbclock.py: `learn_offset`, `shared_now`), and its
heartbeat says how far off it is.

The host's clock is put an hour behind in this process (`timezone.now()` and
`time.time()`, as a board without a battery-backed clock after a power cut); the
database (SQLite, in-process) keeps the true time.
"""

from __future__ import annotations

from datetime import UTC, datetime

import pytest
from django.utils import timezone

from jobs.models import Job
from printers import dbclock
from printers.heartbeat import HostRegistration
from printers.hosts import WorkerHost
from printers.models import ResponseLine
from printers.sample_gcode import segments
from printers.worker.loop import PrinterWorker
from tests.conftest import wait_for

pytestmark = pytest.mark.django_db

HOUR = 3600.0


def near_database_time(when: datetime, seconds: float = 120.0) -> bool:
    """*when* is within *seconds* of the database's time now (an hour off is not)."""
    return abs((when - dbclock.database_now()).total_seconds()) < seconds


def test_the_offset_is_learned_and_stamps_follow_the_database(hour_behind) -> None:
    measured = dbclock.learn_offset()
    assert measured == pytest.approx(HOUR, abs=1.0)
    assert dbclock.clock_offset() == measured
    assert near_database_time(dbclock.shared_now(), 1.0)
    shared = datetime.fromtimestamp(dbclock.shared_time(), UTC)
    assert near_database_time(shared, 1.0)
    assert not near_database_time(timezone.now(), 1000)


def test_a_clock_kept_by_ntp_is_taken_as_right(monkeypatch) -> None:
    monkeypatch.setattr(dbclock, "_offset", 12.0)
    measured = dbclock.learn_offset()
    assert measured is not None and abs(measured) < dbclock.OFFSET_NEGLIGIBLE
    assert dbclock.clock_offset() == 0.0


def test_a_worker_an_hour_behind_stamps_its_print_by_the_database(
    hour_behind, sim_factory, make_printer, make_job
) -> None:
    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "0")
    printer = make_printer(port=str(sim.link), baud=250000)
    worker = PrinterWorker(printer)
    worker.start()
    try:
        job = make_job(printer, segments(5000))
        saved = lambda: Job.objects.get(pk=job.pk)
        wait_for(lambda: saved().progress_at, 10, "a progress save", step=worker.tick)
        printing = saved()
        wait_for(lambda: saved().state == "completed", 60, "the job", step=worker.tick)
        worker.log.flush()
    finally:
        worker.stop()
    done = saved()
    assert near_database_time(printing.started_at)
    assert near_database_time(printing.progress_at)
    assert near_database_time(done.finished_at)
    assert done.elapsed_seconds() < 60  # not an hour
    last = ResponseLine.objects.filter(printer=printer).order_by("-seq").first()
    assert near_database_time(last.time)


def test_the_heartbeat_reports_the_offset_and_the_dashboard_warns(hour_behind) -> None:
    WorkerHost.objects.create(name="shelf-1")
    registration = HostRegistration("shelf-1")
    registration.claim()
    assert registration.beat({})
    host = WorkerHost.objects.get(name="shelf-1")
    assert host.load["clock_offset_s"] == pytest.approx(HOUR, abs=1.0)
    assert host.clock_warning() == (
        "its clock is 3600 s behind the database's: set up NTP"
    )
