"""Upkeep end to end: Celery beat sends every upkeep task on its schedule and a real
Celery worker (the filesystem broker, as `make run` has it) runs them against a
host's database and files: what is past its limit goes, the rest stays."""

from __future__ import annotations

import re
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import pytest

from tests.conftest import wait_for
from tests.hosts import Host

pytestmark = pytest.mark.slow

OLD_SHA, KEPT_SHA, ORPHAN_SHA = "a" * 64, "b" * 64, "c" * 64
SEED = f"""
import json, os
from datetime import timedelta
from pathlib import Path
from django.conf import settings
from django.utils import timezone
from jobs.models import FileAnalysis, Job, Upload
from printers.models import Printer, ResponseLine, TemperatureSample
now = timezone.now()
day = timedelta(days=1)
printer = Printer.objects.create(name="MK3", slug="mk3", port="/nonexistent",
    response_log_limit=5)
ResponseLine.objects.bulk_create(ResponseLine(printer=printer, seq=s, time=now,
    text=f"line {{s}}", kind=2) for s in range(1, 21))
TemperatureSample.objects.create(printer=printer, time=now - 25 * day / 24)
TemperatureSample.objects.create(printer=printer, time=now - day / 24)
storage = Path(settings.JOB_STORAGE_DIR) / "mk3"
(storage / ".uploads").mkdir(parents=True)
def aged(path, when):
    os.utime(path, (when.timestamp(), when.timestamp()))
for name, when in (("old", now - 2 * day), ("new", now - day / 24)):
    part = storage / ".uploads" / f"{{name:0<32}}.part"
    part.write_bytes(b"G28")
    aged(part, when)
    Upload.objects.create(id=f"{{name:0<32}}", printer=printer, name=name,
        path=str(part.relative_to(settings.JOB_STORAGE_DIR)))
    Upload.objects.filter(pk=f"{{name:0<32}}").update(updated_at=when)
for name, sha, ended in (("old", "{OLD_SHA}", now - 40 * day),
                         ("kept", "{KEPT_SHA}", now - day)):
    (storage / f"{{name}}.gcode").write_bytes(b"G28")
    Job.objects.create(printer=printer, name=name, file=f"mk3/{{name}}.gcode",
        sha256=sha, state="completed", finished_at=ended)
for sha in ("{OLD_SHA}", "{KEPT_SHA}", "{ORPHAN_SHA}"):
    FileAnalysis.objects.create(sha256=sha, profile="0" * 16, state="done")
    folder = Path(settings.ANALYSIS_DIR) / sha
    folder.mkdir(parents=True)
    (folder / "16x16.png").write_bytes(b"png")
    aged(folder / "16x16.png", now - 3 * day)
    aged(folder, now - 3 * day)
"""


@pytest.fixture
def host(tmp_path: Path) -> Host:
    made = Host(tmp_path)
    made.env["PRINTHOST_CELERY_QUEUE"] = "upkeep-test"
    for name in ("RESPONSE_LOG", "TEMPERATURE", "UPLOADS", "JOB_FILES", "ANALYSES"):
        made.env[f"PRINTHOST_UPKEEP_{name}_SECONDS"] = "1"
    made.migrate()
    made.shell(SEED)
    return made


@contextmanager
def celery(host: Host, *args: str) -> Iterator[Path]:
    """`python -m celery --app printhost <args>` as runhost starts it; yields its log."""
    with host.celery(*args, log_name=f"{args[0]}.log"):
        yield host.folder / f"{args[0]}.log"


def state(host: Host) -> dict[str, object]:
    """What the upkeep acts on, read in one query."""
    (row,) = host.query(
        "SELECT (SELECT group_concat(seq) FROM printers_responseline),"
        " (SELECT count(*) FROM printers_temperaturesample),"
        " (SELECT group_concat(name) FROM jobs_upload),"
        " (SELECT group_concat(name) FROM jobs_job WHERE file_removed_at IS NOT NULL),"
        " (SELECT count(*) FROM jobs_job),"
        " (SELECT count(*) FROM jobs_fileanalysis)"
    )
    names = ("lines", "samples", "uploads", "removed", "jobs", "analyses")
    return dict(zip(names, row, strict=True))


def test_beat_runs_every_upkeep_task_in_a_real_worker(host: Host) -> None:
    storage, analysis = host.folder / "jobs" / "mk3", host.folder / "analysis"
    done = {
        "lines": "16,17,18,19,20",
        "samples": 1,
        "uploads": "new",
        "removed": "old",
        "jobs": 2,
        "analyses": 1,
    }
    with ExitStack() as stack:
        worker = stack.enter_context(
            celery(host, "worker", "--concurrency", "1", "--hostname",
                   "upkeep@test", "--without-gossip", "--without-mingle")
        )  # fmt: skip
        stack.enter_context(
            celery(host, "beat", "--schedule", str(host.folder / "beat-schedule"))
        )
        try:
            wait_for(lambda: state(host) == done, 60, "the upkeep to finish")
        except AssertionError as error:
            raise AssertionError(
                f"{error}: {state(host)}\n{worker.read_text()[-3000:]}"
            ) from None
    log = worker.read_text()
    for task in (
        "printers.tasks.trim_response_logs",
        "printers.tasks.prune_temperature_samples",
        "jobs.tasks.expire_uploads",
        "jobs.tasks.remove_expired_job_files",
        "jobs.tasks.remove_orphaned_analyses",
    ):
        assert re.search(rf"Task {re.escape(task)}\[[^\]]+\] succeeded", log), task
    assert not (storage / "old.gcode").exists()
    assert (storage / "kept.gcode").exists()
    assert sorted(p.name for p in (storage / ".uploads").iterdir()) == [
        f"{'new':0<32}.part"
    ]
    assert sorted(p.name for p in analysis.iterdir()) == [KEPT_SHA]
