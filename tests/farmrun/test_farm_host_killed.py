"""A whole worker host SIGKILLed mid-print (runhost, its workers and its fetcher: one
process group), its printers' boards running on.

Its printers show offline within about the lease time and their runs interrupted;
nobody is handed them (their lease still names the dead workers) and the other
hosts print on with the same workers. Restarted, the host takes the exact line
from its journal, which the simulator's record bears out, and each run is
resumable (a plan from `POST /printer/resume/<slug>`); then the farm finishes
the rest of its queue."""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest

from printers.worker.journal import Journal
from tests.conftest import wait_for
from tests.farmrig import checks

pytestmark = [pytest.mark.slow, pytest.mark.services]

VICTIM = "shelf-2"
#: Lines a killed worker may have written past its last journalled ack: the
#: firmware's 4 command slots and what its 127-byte receive buffer holds.
IN_FLIGHT = 8
#: The reaper's period and the workers' renewals (a fifth of the lease) on top.
OFFLINE_SLACK = 2.5


def _journal(farm, slug: str):
    entry = Journal(farm.ids[slug], farm.shelves[VICTIM].folder / "journal").last()
    assert entry is not None, f"{slug}: nothing journaled"
    return entry


def _quiet(farm, slugs: list[str]) -> Callable[[], bool]:
    """A predicate: the simulators of *slugs* ran nothing new for a second."""
    seen = {"count": -1, "since": time.monotonic()}

    def predicate() -> bool:
        count = sum(len(farm.sims[s].executed()) for s in slugs)
        if count != seen["count"]:
            seen.update(count=count, since=time.monotonic())
        return time.monotonic() - seen["since"] >= 1.0

    return predicate


def _plan_state(client, slug: str, plan: int) -> str:
    answer = client.get(f"/printer/resume/{slug}", params={"plan": plan})
    return answer.json()["data"]["state"]


def test_a_killed_worker_host_leaves_its_runs_interrupted_and_resumable(make_farm):
    farm = make_farm()
    farm.start()
    farm.upload()
    victims = [p.slug for p in farm.printers if p.host == VICTIM]
    others = [p.slug for p in farm.printers if p.host != VICTIM]
    farm.mid_print(victims, 0.25, timeout=60)
    owners = farm.lease_owners()
    farm.hold_beds |= set(victims)

    farm.runhosts[VICTIM].kill()
    killed_at = time.monotonic()
    offline = lambda: {s for s, st in farm.query(
        "SELECT slug, state FROM printers_printer") if st == "offline"}  # fmt: skip
    lease = farm.config.lease_seconds
    farm.tend(lambda: set(victims) <= offline(), lease + 10, "offline printers")
    took = time.monotonic() - killed_at
    assert took <= lease + OFFLINE_SLACK, f"offline after {took:.1f} s"
    assert offline() == set(victims)
    interrupted = dict(farm.query(
        "SELECT p.slug, j.id FROM jobs_job j JOIN printers_printer p "
        "ON p.id = j.printer_id WHERE j.state = 'interrupted'"))  # fmt: skip
    assert set(interrupted) == set(victims)
    assert {s: farm.lease_owners()[s] for s in victims} == {
        s: owners[s] for s in victims
    }, "a dead host's printer was handed on"

    # The boards finish what they were sent and stop; nobody drives them.
    wait_for(_quiet(farm, victims), 20, "the killed host's printers to stop")
    journal = {slug: _journal(farm, slug) for slug in victims}
    ran = {}
    for slug in victims:
        entry = journal[slug]
        assert entry.job_id == interrupted[slug]
        jobs = checks.jobs_of(farm, slug)
        before = sum(
            len(checks.job_commands(farm.uploaded[f].text()))
            for j, *_rest, f in jobs
            if j != entry.job_id
        )
        farm_job = next(f for j, *_rest, f in jobs if j == entry.job_id)
        commands = checks.job_commands(farm.uploaded[farm_job].text())
        ran[slug] = checks._prefix(checks.executed(farm, slug)[before:], commands)
        assert entry.acked <= ran[slug] <= entry.acked + IN_FLIGHT, (
            f"{slug}: journal says {entry.acked} acked, the board ran {ran[slug]}"
        )

    farm.start_host(VICTIM)
    waiting = lambda: {s for s, st in farm.query(
        "SELECT slug, state FROM printers_printer") if st == "waitstart"}  # fmt: skip
    farm.tend(lambda: set(victims) <= waiting(), 60, "the host's printers back")
    workers = farm.runhosts[VICTIM].workers()
    with farm.api() as client:
        for slug in victims:
            job = interrupted[slug]
            state, acked, message = farm.query(
                "SELECT state, lines_acked, message FROM jobs_job WHERE id = %s", job
            )[0]
            assert (state, acked) == ("interrupted", journal[slug].acked), message
            owner = farm.lease_owners()[slug]
            assert int(owner.split(":")[1]) == workers[slug], "not its host's worker"
            response = client.post(f"/printer/resume/{slug}", json={"id": job})
            assert response.status_code == 200, response.text
            plan = response.json()["data"]
            assert plan["line"] == acked
            wait_for(
                lambda s=slug, p=plan["id"]: _plan_state(client, s, p) == "ready",
                30, "the resume plan",
            )  # fmt: skip
    assert all(len(farm.owners[s]) == 1 for s in others), (
        "another host's worker changed"
    )

    farm.hold_beds.clear()
    farm.run_to_end(timeout=120)
    checks.jobs_ran_once(
        farm, allowed=dict.fromkeys(interrupted.values(), "interrupted")
    )
    checks.matching_printers(farm)
    checks.records_match(
        farm,
        cut_short={interrupted[s]: (journal[s].acked, ran[s]) for s in victims},
    )
