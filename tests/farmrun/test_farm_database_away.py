"""PostgreSQL goes away mid-print for longer than the lease, for the whole farm: every
process (control plane, dispatcher, Celery, every worker host and worker) reaches
it through one TCP proxy the test cuts, then restores.

Every print goes on and completes; nothing is lost from the response log (ids
contiguous, every job command logged as sent) or the progress; no printer is
driven twice (one lease owner per printer all along, no lease lost)."""

from __future__ import annotations

import time

import pytest

from tests.conftest import wait_for
from tests.farmrig import checks

pytestmark = [pytest.mark.slow, pytest.mark.services]

#: Longer than the lease (3 s): every lease has run out when the database is back.
CUT_SECONDS = 5.0


def test_every_print_completes_with_the_database_away_for_longer_than_the_lease(
    make_farm,
):
    farm = make_farm(proxy_postgres=True)
    farm.start()
    farm.upload()
    printers = [p.slug for p in farm.printers]
    farm.mid_print(printers, 0.2, timeout=60)
    executed = lambda: sum(len(checks.executed(farm, slug)) for slug in printers)
    at_cut = executed()

    farm.postgres_proxy.cut()
    cut_at = time.monotonic()
    # The firmware goes on running lines while no process reaches the database.
    wait_for(lambda: executed() > at_cut + 1000, 30, "the prints to go on")
    wait_for(lambda: time.monotonic() - cut_at >= CUT_SECONDS, 30, "the cut")
    assert all(r.alive() for r in farm.runhosts.values())
    farm.postgres_proxy.restore()
    farm.run_to_end(timeout=120)

    checks.jobs_ran_once(farm)
    checks.matching_printers(farm)
    checks.records_match(farm)
    checks.response_log_whole(farm)
    progress = farm.query("SELECT lines_acked, line_count FROM jobs_job")
    assert all(acked == count for acked, count in progress)
    # One driver per printer: no worker was replaced, no lease changed hands.
    assert {slug: len(seen) for slug, seen in farm.owners.items()} == dict.fromkeys(
        printers, 1
    )
    logs = farm.logs()
    assert "LeaseLost" not in logs and "lease lost" not in logs
    assert "the database does not answer" in logs and "answers again" in logs
