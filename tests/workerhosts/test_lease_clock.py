"""A lease is written and judged by the database's clock, never a host's own: a
worker host whose wall clock is off, or stepped by NTP mid-print, neither loses the
printer it renews nor keeps a dead one looking alive (printers/dbclock.py)."""

from __future__ import annotations

import time
from datetime import timedelta
from unittest import mock

import pytest
from django.utils import timezone

from jobs.farm.matching import busy_reason
from printers.models import Printer
from printers.reaper import reap_silent_workers
from printers.worker.lease import Lease, make_owner
from tests.conftest import wait_for

pytestmark = pytest.mark.django_db(transaction=True)

LEASE_SECONDS = 10.0


def _skewed(seconds: float) -> mock._patch:
    """This host's wall clock *seconds* off (every `timezone.now()` in this
    process: the worker's own and the control plane's code alike)."""
    real = timezone.now
    return mock.patch("django.utils.timezone.now", lambda: real() + timedelta(
        seconds=seconds))  # fmt: skip


@pytest.mark.parametrize("skew", [-20.0, +20.0])
def test_a_host_whose_clock_is_off_keeps_the_printer_it_renews(make_printer, skew):
    printer = make_printer(state=Printer.State.IDLE)
    lease = Lease(printer.pk, make_owner(), LEASE_SECONDS, host="")
    with _skewed(skew):
        lease.take(time.monotonic())
        lease.check()  # its own check: still its lease
        with lease.held(state=Printer.State.PRINTING):
            pass
    # The control plane (its clock right) sees a live worker: nothing reaped,
    # and the printer is not offline to the farm.
    assert reap_silent_workers() == []
    row = Printer.objects.get(pk=printer.pk)
    assert row.state == Printer.State.PRINTING
    assert busy_reason(row, has_work=False) == "printing"


def test_a_clock_stepped_forward_mid_lease_does_not_lose_the_printer(make_printer):
    """NTP steps a board's clock past the lease's end right after a renewal: the
    lease still runs by the database's clock, so the next write goes in."""
    printer = make_printer()
    lease = Lease(printer.pk, make_owner(), LEASE_SECONDS, host="")
    lease.take(time.monotonic())
    with _skewed(LEASE_SECONDS + 2):
        lease.check()
        with lease.held(state=Printer.State.PRINTING):
            pass
    assert not lease.lost


def test_a_dead_host_whose_clock_ran_ahead_is_reaped_when_its_lease_ends(
    make_printer,
):
    """Its clock a minute ahead, the host wrote its lease; then it died. The lease
    ends when the database's clock says so, not a minute later."""
    printer = make_printer(state=Printer.State.PRINTING)
    lease = Lease(printer.pk, make_owner(), 0.3, host="")
    with _skewed(60):
        lease.take(time.monotonic())
    wait_for(
        lambda: printer.pk in reap_silent_workers(), 10,
        "the dead host's printer reaped (its clock a minute ahead)",
    )  # fmt: skip
    assert Printer.objects.get(pk=printer.pk).state == Printer.State.OFFLINE


#: The same on PostgreSQL, in a process of its own: a host 20 s behind renews and
#: writes, one stepped 12 s forward writes, and neither the reaper nor the farm
#: takes its printer for dead (the farm reads the lease through printer_rows()).
ON_POSTGRES = """
import time
from datetime import timedelta
from unittest import mock
from django.utils import timezone
from jobs.farm.matching import farm_printers
from printers.models import Printer
from printers.reaper import reap_silent_workers
from printers.worker.lease import Lease, make_owner
real = timezone.now
printer = Printer.objects.create(name="P", slug="p", port="/nonexistent",
    state="idle", farm=True)
lease = Lease(printer.pk, make_owner(), 10.0, host="")
with mock.patch("django.utils.timezone.now", lambda: real() - timedelta(seconds=20)):
    lease.take(time.monotonic())
    with lease.held(state="idle"):
        pass
with mock.patch("django.utils.timezone.now", lambda: real() + timedelta(seconds=12)):
    lease.check()
    with lease.held(state="idle"):
        pass
(facts,) = farm_printers()
print("reaped", reap_silent_workers(), "busy", repr(facts.extra["busy"]))
"""


@pytest.mark.services
def test_on_postgresql_the_databases_clock_decides_too(tmp_path) -> None:
    import psycopg

    from tests.hosts import Host, postgres_url

    url = postgres_url()
    try:
        host = Host(tmp_path, database_url=url)
        host.migrate()
        assert host.shell(ON_POSTGRES).splitlines()[-1] == "reaped [] busy ''"
    finally:
        admin = url.rsplit("/", 1)[0] + "/postgres"
        with psycopg.connect(admin, autocommit=True) as db:
            db.execute(f"DROP DATABASE IF EXISTS {url.rsplit('/', 1)[1]} WITH (FORCE)")
