"""The whole farm, no faults: a control plane and three worker hosts (separate
process groups, data directories and host keys) on one PostgreSQL and Redis; jobs
with mixed requirements uploaded to the farm queue run once each, on a printer that
meets them, and each simulator ran exactly its jobs' files."""

from __future__ import annotations

import pytest

from tests.farmrig import checks

pytestmark = [pytest.mark.slow, pytest.mark.services]


def test_every_farm_job_runs_once_on_a_matching_printer(make_farm):
    farm = make_farm()
    farm.start()
    farm.upload()
    farm.run_to_end(timeout=150)

    checks.jobs_ran_once(farm)
    checks.matching_printers(farm)
    checks.records_match(farm)
    checks.response_log_whole(farm)
    hosts = {
        slug: host
        for slug, host in farm.query(
            "SELECT p.slug, h.name FROM printers_printer p "
            "JOIN printers_workerhost h ON h.id = p.worker_host_id"
        )
    }
    used = {hosts[slug] for _f, _j, slug, *_ in checks.runs(farm)}
    assert used == set(farm.host_names), "every worker host printed"
    logs = farm.logs()
    assert "LeaseLost" not in logs and "Traceback" not in logs
