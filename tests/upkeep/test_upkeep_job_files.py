"""Upkeep: finished jobs' files past their printer's `job_file_days` are removed by
beat; the job rows stay as history, a file another job still needs stays, and a
reprint of a job whose file was removed says so (410) and queues nothing."""

from __future__ import annotations

import json
from datetime import timedelta
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
from django.contrib.auth import get_user_model
from django.test import Client
from django.utils import timezone

from jobs import services
from jobs.models import FileAnalysis, Job, ResumePlan
from jobs.upkeep import remove_expired_job_files
from tests.upkeep.conftest import analysed, finish

if TYPE_CHECKING:
    from collections.abc import Callable

    from printers.models import Printer

pytestmark = pytest.mark.django_db

DAY = timedelta(days=1)
FINISHED = ["completed", "aborted", "failed", "interrupted"]
NONE_REMOVED = {"files": 0, "jobs": 0, "analyses": 0, "folders": 0}


@pytest.mark.parametrize("state", ["completed", "aborted", "failed"])
def test_a_finished_job_past_the_retention_loses_its_file_and_keeps_its_row(
    make_printer: Callable[..., Printer], make_job: Callable[..., Job], state: str
) -> None:
    now = timezone.now()
    printer = make_printer()  # job_file_days: 30 by default
    job = finish(
        make_job(printer, "G28\n"), state, now - 30 * DAY - timedelta(seconds=1)
    )
    path = job.path

    assert remove_expired_job_files(now=now)["files"] == 1

    assert not path.exists()
    job.refresh_from_db()
    assert (job.state, job.file_removed_at) == (state, now)
    assert job.file  # the row still says which file it printed


@pytest.mark.parametrize(
    ("state", "finished_ago"),
    [
        ("completed", 30 * DAY),  # exactly the retention
        ("aborted", 29 * DAY),
        ("interrupted", timedelta(minutes=5)),
        ("failed", None),  # no end time: kept
        ("queued", 90 * DAY),  # requeued after it finished long ago
        ("stored", 90 * DAY),
        ("printing", 90 * DAY),
        ("paused", 90 * DAY),
    ],
)
def test_a_job_not_past_the_retention_keeps_its_file(
    make_printer: Callable[..., Printer],
    make_job: Callable[..., Job],
    state: str,
    finished_ago: timedelta | None,
) -> None:
    now = timezone.now()
    printer = make_printer()
    at = None if finished_ago is None else now - finished_ago
    job = finish(make_job(printer, "G28\n"), state, at)

    assert remove_expired_job_files(now=now) == NONE_REMOVED

    assert job.path.exists()
    job.refresh_from_db()
    assert job.file_removed_at is None


def test_each_printer_has_its_own_retention_and_0_keeps_forever(
    make_printer: Callable[..., Printer], make_job: Callable[..., Job]
) -> None:
    now = timezone.now()
    week = make_printer(job_file_days=7)
    forever = make_printer(job_file_days=0)
    default = make_printer()
    short = finish(make_job(week, "G28\n"), "completed", now - 10 * DAY)
    kept = [
        finish(make_job(forever, "G28\n"), "completed", now - 3650 * DAY),
        finish(make_job(default, "G28\n"), "completed", now - 10 * DAY),
        finish(make_job(week, "G28\n"), "completed", now - 6 * DAY),
    ]

    assert remove_expired_job_files(now=now)["files"] == 1

    assert not short.path.exists()
    assert all(job.path.exists() for job in kept)
    assert list(
        Job.objects.filter(file_removed_at__isnull=False).values_list("pk", flat=True)
    ) == [short.pk]


@pytest.mark.parametrize("state", ["queued", "printing", "paused", "stored"])
def test_a_file_another_job_still_needs_is_kept(
    make_printer: Callable[..., Printer], make_job: Callable[..., Job], state: str
) -> None:
    now = timezone.now()
    printer = make_printer()
    old = finish(make_job(printer, "G28\n"), "completed", now - 60 * DAY)
    again = services.reprint(old)  # shares the stored file
    assert again.file == old.file
    # Its state decides, even with an end time from an earlier run.
    Job.objects.filter(pk=again.pk).update(state=state, finished_at=now - 60 * DAY)

    assert remove_expired_job_files(now=now) == NONE_REMOVED
    assert old.path.exists()
    assert not Job.objects.filter(file_removed_at__isnull=False).exists()


def test_a_shared_file_goes_once_every_job_naming_it_is_past_its_retention(
    make_printer: Callable[..., Printer], make_job: Callable[..., Job]
) -> None:
    now = timezone.now()
    printer = make_printer()
    first = finish(make_job(printer, "G28\n"), "completed", now - 60 * DAY)
    again = finish(services.reprint(first), "aborted", now - 2 * DAY)

    assert remove_expired_job_files(now=now)["files"] == 0
    assert first.path.exists()

    finish(again, "aborted", now - 31 * DAY)
    assert remove_expired_job_files(now=now)["files"] == 1
    assert not first.path.exists()
    assert set(
        Job.objects.filter(file_removed_at=now).values_list("pk", flat=True)
    ) == {first.pk, again.pk}


def test_the_analysis_goes_with_the_file_unless_another_stored_file_has_it(
    make_printer: Callable[..., Printer], make_job: Callable[..., Job]
) -> None:
    now = timezone.now()
    printer = make_printer()
    # Two uploads of one file: two stored files, one SHA-256, one analysis.
    shared_old = finish(
        make_job(printer, "G28\n", "a.gcode"), "completed", now - 40 * DAY
    )
    shared_new = make_job(printer, "G28\n", "b.gcode")
    alone = finish(make_job(printer, "G1 X5\n", "c.gcode"), "failed", now - 40 * DAY)
    assert shared_old.sha256 == shared_new.sha256 != alone.sha256
    shared_folder = analysed(shared_old.sha256, at=now - 40 * DAY)
    alone_folder = analysed(alone.sha256, at=now - 40 * DAY)

    assert remove_expired_job_files(now=now) == {
        "files": 2, "jobs": 2, "analyses": 1, "folders": 1,
    }  # fmt: skip

    assert not shared_old.path.exists()
    assert shared_new.path.exists()
    assert shared_folder.exists()
    assert FileAnalysis.objects.filter(sha256=shared_old.sha256).exists()
    assert not alone_folder.exists()
    assert not FileAnalysis.objects.filter(sha256=alone.sha256).exists()
    alone.refresh_from_db()
    assert alone.analysis is None  # the row stays, without the analysis


def test_a_file_already_gone_from_disk_is_marked_all_the_same(
    make_printer: Callable[..., Printer], make_job: Callable[..., Job]
) -> None:
    now = timezone.now()
    job = finish(make_job(make_printer(), "G28\n"), "completed", now - 40 * DAY)
    job.path.unlink()
    assert remove_expired_job_files(now=now)["jobs"] == 1
    job.refresh_from_db()
    assert job.file_removed_at == now


def test_a_row_naming_a_file_outside_the_storage_is_left_alone(
    make_printer: Callable[..., Printer], make_job: Callable[..., Job], tmp_path: Path
) -> None:
    now = timezone.now()
    outside = tmp_path / "elsewhere.gcode"
    outside.write_text("G28\n")
    job = finish(make_job(make_printer(), "G28\n"), "completed", now - 40 * DAY)
    Job.objects.filter(pk=job.pk).update(file="../elsewhere.gcode")
    assert remove_expired_job_files(now=now) == NONE_REMOVED
    assert outside.exists()


def call(method: str, path: str, key: str, **kwargs: object) -> tuple[int, dict]:
    response = getattr(Client(), method)(path, HTTP_X_API_KEY=key, **kwargs)
    return response.status_code, json.loads(response.content or b"{}")


def test_a_reprint_of_a_job_whose_file_was_removed_says_so_and_queues_nothing(
    make_printer: Callable[..., Printer],
    make_job: Callable[..., Job],
    operator_key: Callable[[], str],
) -> None:
    now = timezone.now()
    printer = make_printer(slug="mk3", state="idle")
    job = finish(make_job(printer, "G28\n", "part.gcode"), "completed", now - 31 * DAY)
    remove_expired_job_files(now=now)
    key, jobs = operator_key(), Job.objects.count()

    status, body = call("post", f"/printer/job/mk3?a=reprint&id={job.pk}", key)
    assert status == 410
    assert body["error"] == (
        f"job {job.pk} (part.gcode): its file was removed on {now:%Y-%m-%d}, 30 days "
        "after the job ended (the printer's job_file_days); upload the file again "
        "to print it"
    )
    name = job.file.rsplit("/", 1)[-1]
    status, body = call(
        "post", f"/api/files/local/{name}", key,
        data=json.dumps({"command": "select", "print": True}),
        content_type="application/json",
    )  # fmt: skip
    assert (status, "upload the file again" in body["error"]) == (410, True)
    status, body = call("post", f"/printer/print/start?filename={name}", key)
    assert status == 410
    assert "its file was removed" in body["error"]["message"]

    assert Job.objects.count() == jobs
    job.refresh_from_db()
    assert (job.state, job.file_removed_at) == ("completed", now)


def test_the_admin_does_not_queue_again_a_job_whose_file_was_removed(
    make_printer: Callable[..., Printer], make_job: Callable[..., Job]
) -> None:
    now = timezone.now()
    printer = make_printer()
    gone = finish(make_job(printer, "G28\n"), "completed", now - 31 * DAY)
    kept = finish(make_job(printer, "G1 X1\n"), "completed", now - DAY)
    remove_expired_job_files(now=now)
    admin = get_user_model().objects.create_superuser("root", password="x")
    client = Client()
    client.force_login(admin)
    response = client.post(
        "/admin/jobs/job/",
        {"action": "requeue", "_selected_action": [gone.pk, kept.pk]},
        follow=True,
    )
    assert "their files were removed" in response.content.decode()
    states = dict(Job.objects.values_list("pk", "state"))
    assert (states[gone.pk], states[kept.pk]) == ("completed", "queued")


def test_an_interrupted_run_keeps_its_file_until_it_is_resumed(
    make_printer: Callable[..., Printer], make_job: Callable[..., Job]
) -> None:
    now, long_ago = timezone.now(), timezone.now() - 90 * DAY
    stopped = finish(make_job(make_printer(), "G28\nG1 X1\n"), "interrupted", long_ago)

    assert remove_expired_job_files(now=now)["files"] == 0  # a part waits for it
    assert stopped.path.exists()

    resumed = Job.objects.create(
        printer=stopped.printer, name=stopped.name, file=stopped.file,
        sha256=stopped.sha256, resume_of=stopped, state="completed",
        finished_at=long_ago,
    )  # fmt: skip
    assert remove_expired_job_files(now=now)["jobs"] == 2
    assert not stopped.path.exists()
    resumed.refresh_from_db()
    assert resumed.file_removed_at == now


def test_a_resume_plan_not_started_keeps_the_file_of_an_old_failed_run(
    make_printer: Callable[..., Printer], make_job: Callable[..., Job]
) -> None:
    now = timezone.now()
    failed = finish(make_job(make_printer(), "G28\n"), "failed", now - 90 * DAY)
    plan = ResumePlan.objects.create(job=failed, line=0, state="ready")

    assert remove_expired_job_files(now=now)["files"] == 0
    assert failed.path.exists()
    ResumePlan.objects.filter(pk=plan.pk).update(state="started")
    assert remove_expired_job_files(now=now)["files"] == 1


def test_the_admin_queues_a_resumed_run_again_as_the_whole_file(
    make_printer: Callable[..., Printer], make_job: Callable[..., Job]
) -> None:
    """Queued again from the start, over a bed to be cleared: not its preamble, which
    goes back to the height the first run stopped at, in mid-air now."""
    job = make_job(make_printer(), "G28\nG1 X1\nG1 X2\n")
    Job.objects.filter(pk=job.pk).update(
        state="failed", start_line=2, start_offset=10, preamble="G92 Z5.2",
        start_objects={"active": "box"},
    )  # fmt: skip
    admin = get_user_model().objects.create_superuser("root", password="x")
    client = Client()
    client.force_login(admin)
    client.post("/admin/jobs/job/", {"action": "requeue", "_selected_action": [job.pk]})
    job.refresh_from_db()
    assert job.state == "queued" and not job.is_resume
    assert (job.start_line, job.start_offset, job.preamble) == (0, 0, "")
    assert job.start_objects == {}
