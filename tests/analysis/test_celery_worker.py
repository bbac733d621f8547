"""Analysis in a real Celery worker, with the embedded filesystem broker (`make run`)
and with Redis (a farm, CI): a worker killed mid-analysis, and the next one.

runhost's own Celery worker and beat are in tests/live/test_make_run_slicer.py."""

from __future__ import annotations

import os
import signal
import subprocess
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from tests.conftest import wait_for
from tests.hosts import Host, redis_url

pytestmark = pytest.mark.slow

DATA = Path(__file__).resolve().parent.parent / "data"
PRUSA = DATA / "prusaslicer-2.5_box-and-cylinder.gcode"


@pytest.fixture(params=["filesystem", "redis"])
def host(request: pytest.FixtureRequest, tmp_path: Path) -> Host:
    redis = redis_url() if request.param == "redis" else ""
    made = Host(tmp_path, redis=redis)
    # Tests share one Redis: each gets its own queue.
    made.env["PRINTHOST_CELERY_QUEUE"] = f"test-{uuid.uuid4().hex[:8]}"
    made.env["PRINTHOST_ANALYSIS_STALE_SECONDS"] = "2"
    made.migrate()
    made.shell(
        "from printers.models import Printer; Printer.objects.create("
        "name='MK3', slug='mk3', port='/nonexistent')"
    )
    return made


@contextmanager
def celery_worker(host: Host, name: str) -> Iterator[subprocess.Popen]:
    """A Celery worker as runhost starts it, in its own process group."""
    with host.celery(
        "worker", "--concurrency", "1", "--hostname", f"{name}@test",
        "--without-gossip", "--without-mingle", log_name=f"{name}.log",
    ) as process:  # fmt: skip
        yield process


def analysis_row(host: Host) -> tuple:
    rows = host.query(
        "SELECT state, attempts, worker, reason, "
        "heartbeat_at < datetime('now', '-2 seconds') FROM jobs_fileanalysis"
    )
    assert len(rows) <= 1, rows
    return rows[0] if rows else ()


def worker_log(host: Host, name: str) -> str:
    return (host.folder / f"{name}.log").read_text(errors="replace")[-3000:]


def test_a_worker_killed_mid_analysis_is_finished_once_after_restart(
    host: Host,
) -> None:
    big = host.folder / "big.gcode"
    body = PRUSA.read_bytes()
    with big.open("wb") as out:  # ~8 MB: seconds of analysis, far more than a poll
        for copy in range(32):
            out.write(body.replace(b"G28 ", f"G28 ; copy {copy}\n".encode(), 1))
    host.manage("add_job", "mk3", str(big))
    with celery_worker(host, "first") as first:
        wait_for(
            lambda: analysis_row(host)[:1] == ("running",), 60,
            f"the analysis to start:\n{worker_log(host, 'first')}",
        )  # fmt: skip
        os.killpg(first.pid, signal.SIGKILL)  # the host loses power
        first.wait()
    state, attempts, worker, *_ = analysis_row(host)
    assert (state, attempts) == ("running", 1)
    # Its heartbeat goes stale; the next worker to start sweeps it up.
    wait_for(lambda: analysis_row(host)[4] == 1, 30, "the heartbeat to go stale")
    with celery_worker(host, "second"):
        wait_for(
            lambda: analysis_row(host)[0] == "done", 120,
            f"the analysis to finish after restart:\n{worker_log(host, 'second')}",
        )  # fmt: skip
    state, attempts, again, reason, _ = analysis_row(host)
    assert (state, attempts, reason) == ("done", 2, "")
    assert again != worker
    commands = host.shell(
        "from jobs.analysing import analysis_of; from jobs.models import Job; "
        "job = Job.objects.get(); print(analysis_of(job).commands == job.line_count)"
    )
    assert commands.splitlines()[-1] == "True"
