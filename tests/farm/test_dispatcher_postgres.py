"""Dispatchers on real PostgreSQL: racing threads (each with its own connection) never
give a job twice or a printer two jobs, and a dispatcher killed inside its claim's
transaction gives nothing while another one carries on.

Printers are made ready as their workers leave them (idle, lease held); no worker
runs, so a given job stays queued and its printer stays busy.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections import Counter
from typing import TYPE_CHECKING

import pytest

from tests.conftest import ROOT, wait_for
from tests.farm.conftest import box_gcode
from tests.hosts import Host, postgres_url

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

pytestmark = pytest.mark.services

#: Printers made ready, and farm jobs (one shared file, analysed once).
SETUP = """
import io
from datetime import timedelta
from django.utils import timezone
from jobs.analysis_task import run
from jobs.farm.requirements import Requirements
from jobs.farm.storing import store_farm_upload
from printers.models import Printer
for n in range({printers}):
    Printer.objects.create(name=f"P{{n}}", slug=f"p{{n:02d}}", port="/nonexistent",
        build_volume={{"min": [0, 0, 0], "max": [250, 210, 210]}}, state="idle",
        lease_owner="test", lease_expires_at=timezone.now() + timedelta(hours=1))
for n in range({jobs}):
    farm_job = store_farm_upload(io.BytesIO({text!r}.encode()), name=f"j{{n:02d}}.gcode",
        requirements=Requirements())
print(run(farm_job.analysis_id, worker="test"))
"""

#: Threads that wait for each other, then run passes at once; the hook widens the
#: claim's window so that they collide inside it.
RACE = """
import threading, time
from django.db import connection
from jobs.farm.dispatch import Dispatcher
start = threading.Barrier({threads})
given, lost, errors = [], [], []
def work():
    try:
        start.wait()
        dispatcher = Dispatcher(hook=lambda farm_job, printer: time.sleep(0.01))
        for _ in range(4):
            given.append(dispatcher.run_pass())
        lost.append(dispatcher.lost)
    except Exception as error:
        errors.append(repr(error))
    finally:
        connection.close()
threads = [threading.Thread(target=work) for _ in range({threads})]
for thread in threads: thread.start()
for thread in threads: thread.join()
print("given", sum(given), "lost", sum(lost), "errors", errors)
"""

ASSIGNED = """
SELECT f.name, p.slug, j.id FROM jobs_farmjob f
JOIN printers_printer p ON p.id = f.printer_id JOIN jobs_job j ON j.id = f.job_id
WHERE f.state = 'assigned'
"""


@pytest.fixture
def farm_host(tmp_path: Path) -> Iterator[Host]:
    url = postgres_url()
    host = Host(tmp_path, database_url=url)
    host.migrate()
    yield host
    import psycopg

    with psycopg.connect(url.rsplit("/", 1)[0] + "/postgres", autocommit=True) as db:
        db.execute(f"DROP DATABASE IF EXISTS {url.rsplit('/', 1)[1]} WITH (FORCE)")


def check_each_given_once(host: Host) -> list[tuple[str, str, int]]:
    """Every assigned farm job has one job on one printer, no printer has two jobs,
    and no job exists that no farm job names."""
    assigned = host.query(ASSIGNED)
    jobs = host.query("SELECT p.slug, j.origin FROM jobs_job j JOIN printers_printer p "
                      "ON p.id = j.printer_id")  # fmt: skip
    per_printer = Counter(slug for slug, _ in jobs)
    per_farm_job = Counter(origin.split(":")[0] for _, origin in jobs)
    assert max(per_printer.values(), default=0) <= 1, per_printer
    assert max(per_farm_job.values(), default=0) <= 1, per_farm_job
    assert len(jobs) == len(assigned)
    assert len({slug for _, slug, _ in assigned}) == len(assigned)
    return assigned


def test_racing_dispatchers_give_each_job_once_and_each_printer_one_job(
    farm_host: Host,
) -> None:
    setup = SETUP.format(printers=12, jobs=20, text=box_gcode(100, 50, 30))
    assert farm_host.shell(setup).endswith("done")

    out = farm_host.shell(RACE.format(threads=4)).splitlines()[-1]

    _, given, _, lost, *_ = out.split()
    assert out.endswith("errors []"), out
    assert given == "12", out
    assert int(lost) > 0, f"the dispatchers never collided: {out}"
    assigned = check_each_given_once(farm_host)
    assert len(assigned) == 12
    (waiting,) = farm_host.query(
        "SELECT count(*) FROM jobs_farmjob WHERE state = 'waiting' AND reason LIKE "
        "'every matching printer is busy:%'"
    )[0]
    assert waiting == 8


def test_a_dispatcher_killed_inside_its_claim_gives_nothing_and_blocks_nobody(
    farm_host: Host, tmp_path: Path
) -> None:
    farm_host.shell(SETUP.format(printers=2, jobs=2, text=box_gcode(100, 50, 30)))
    held = tmp_path / "claim-held"
    killed = subprocess.Popen(
        [sys.executable, "manage.py", "run_dispatcher", "--interval", "0.1",
         "--hold-claim", str(held)],
        cwd=ROOT, env=farm_host.env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        wait_for(held.exists, 30, "the dispatcher to hold its claim")
        pid, farm_job, slug = held.read_text().split()
        assert int(pid) == killed.pid and (farm_job, slug) == ("1", "p00")

        # Another dispatcher meanwhile skips the held job and printer, gives the rest.
        farm_host.manage("run_dispatcher", "--once")
        assert [row[:2] for row in check_each_given_once(farm_host)] == [
            ("j01.gcode", "p01")
        ]
        os.kill(killed.pid, signal.SIGKILL)
        killed.wait(timeout=10)
    finally:
        if killed.poll() is None:
            killed.kill()
            killed.wait()
    held.unlink()

    # The killed claim was rolled back: the job waits, and goes once.
    (state,) = farm_host.query("SELECT state FROM jobs_farmjob WHERE id = 1")[0]
    assert state == "waiting"
    farm_host.manage("run_dispatcher", "--once")
    assigned = check_each_given_once(farm_host)
    assert sorted(row[:2] for row in assigned) == [
        ("j00.gcode", "p00"),
        ("j01.gcode", "p01"),
    ]
    stored = sorted(p.name for p in (tmp_path / "jobs").glob("p*/*"))
    assert stored == ["farm1-j00.gcode", "farm2-j01.gcode"]
