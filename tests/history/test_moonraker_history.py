"""Moonraker's history calls (server/history/list, job, totals) in Moonraker's shapes,
after completed, aborted, failed, interrupted and resumed runs."""

from __future__ import annotations

from datetime import timedelta

import pytest
from django.utils import timezone

from jobs.analysing import analysis_of
from jobs.history import HistoryEntry
from jobs.models import Job

pytestmark = pytest.mark.django_db

JOB_FIELDS = {
    "job_id", "user", "filename", "exists", "status", "start_time", "end_time",
    "print_duration", "total_duration", "filament_used", "metadata", "auxiliary_data",
}  # fmt: skip


@pytest.fixture
def runs(farm):
    done = farm.run(farm.p, "alice", "completed", minutes=300)
    aborted = farm.run(farm.p, "alice", "aborted", minutes=250, acked=400)
    failed = farm.run(farm.p, "alice", "failed", minutes=200, message="MAXTEMP")
    cut = analysis_of(done).layers[5].line
    interrupted = farm.run(farm.p, "alice", "interrupted", minutes=150, acked=cut)
    resumed = farm.end(farm.resume(interrupted, cut, minutes=100), "completed")
    farm.run(farm.q, "bob", "completed", minutes=50)
    return {
        "done": done,
        "aborted": aborted,
        "failed": failed,
        "interrupted": interrupted,
        "resumed": resumed,
    }


def result(answer) -> dict:
    assert answer.status_code == 200, answer.content
    return answer.json()["result"]


def test_list_is_the_printers_runs_in_moonrakers_shape_and_statuses(farm, runs):
    data = result(farm.client("alice").get("/p/p/server/history/list"))

    assert data["count"] == 5 == len(data["jobs"])
    assert all(set(job) == JOB_FIELDS for job in data["jobs"])
    assert [j["status"] for j in data["jobs"]] == [
        "completed",  # the resumed run
        "interrupted",
        "error",
        "cancelled",
        "completed",
    ]
    newest = data["jobs"][0]
    entry = HistoryEntry.objects.get(job_number=runs["resumed"].pk)
    assert newest["job_id"] == f"{entry.pk:06X}"
    assert newest["user"] == "alice"
    assert newest["filename"] == runs["resumed"].file.rsplit("/", 1)[-1]
    assert newest["exists"] is True
    assert newest["start_time"] == pytest.approx(entry.started_at.timestamp())
    assert newest["end_time"] == pytest.approx(entry.finished_at.timestamp())
    assert newest["print_duration"] == pytest.approx(100 * 60, abs=5)
    assert newest["filament_used"] == pytest.approx(entry.filament_used)
    assert newest["metadata"]["layer_count"] == 10
    assert newest["metadata"]["slicer"] == "PrusaSlicer"
    assert newest["metadata"]["size"] == runs["resumed"].size_bytes


def test_list_takes_limit_start_order_since_and_before(farm, runs):
    client = farm.client("alice")
    now = timezone.now()

    first_two = result(client.get("/p/p/server/history/list?limit=2&start=1"))
    oldest = result(client.get("/p/p/server/history/list?order=asc&limit=1"))
    since = (now - timedelta(minutes=220)).timestamp()
    before = (now - timedelta(minutes=120)).timestamp()
    window = result(
        client.get(f"/p/p/server/history/list?since={since}&before={before}")
    )

    assert [j["status"] for j in first_two["jobs"]] == ["interrupted", "error"]
    assert first_two["count"] == 2
    assert oldest["jobs"][0]["status"] == "completed"
    assert oldest["jobs"][0]["start_time"] < first_two["jobs"][1]["start_time"]
    assert [j["status"] for j in window["jobs"]] == ["interrupted", "error"]


def test_a_running_run_is_in_progress_and_can_be_asked_for_by_its_uid(farm, runs):
    job = farm.start(farm.job(farm.p, "alice"), minutes_ago=5)
    client = farm.client("alice")

    listed = result(client.get("/p/p/server/history/list"))["jobs"][0]
    one = result(client.get(f"/p/p/server/history/job?uid={listed['job_id']}"))

    assert listed["status"] == "in_progress"
    assert listed["job_id"] == f"job-{job.pk}"
    assert listed["end_time"] is None
    assert one["job"]["status"] == "in_progress"
    # Once it ends, the same uid finds its entry.
    farm.end(Job.objects.get(pk=job.pk), "aborted", acked=10)
    ended = result(client.get(f"/p/p/server/history/job?uid=job-{job.pk}"))
    assert ended["job"]["status"] == "cancelled"


def test_job_by_uid_and_its_file_gone_after_a_delete(farm, runs):
    client = farm.client("alice")
    entry = HistoryEntry.objects.get(job_number=runs["failed"].pk)
    client.post(f"/printer/job/p?a=delete&id={runs['failed'].pk}")

    one = result(client.get(f"/p/p/server/history/job?uid={entry.uid}"))

    assert set(one["job"]) == JOB_FIELDS
    assert one["job"]["status"] == "error"
    assert one["job"]["exists"] is False


def test_totals_add_up_the_printers_ended_runs(farm, runs):
    data = result(farm.client("alice").get("/p/p/server/history/totals"))

    entries = list(HistoryEntry.objects.filter(printer=farm.p))
    totals = data["job_totals"]
    assert set(totals) == {
        "total_jobs", "total_time", "total_print_time", "total_filament_used",
        "longest_job", "longest_print",
    }  # fmt: skip
    assert totals["total_jobs"] == len(entries) == 5
    assert totals["total_time"] == pytest.approx(
        sum(e.print_seconds for e in entries), abs=0.1
    )
    assert totals["total_filament_used"] == pytest.approx(
        sum(e.filament_used for e in entries), abs=0.1
    )
    assert totals["longest_job"] == pytest.approx(300 * 60, abs=5)
    assert data["auxiliary_totals"] == []


@pytest.mark.parametrize(
    ("path", "status", "words"),
    [
        ("/p/nope/server/history/list", 404, "Unknown printer 'nope'"),
        ("/p/p/server/history/list?limit=-1", 400, "limit must be 0 or more"),
        ("/p/p/server/history/list?start=-5", 400, "start must be 0 or more"),
        ("/p/p/server/history/list?since=noon", 400, "since must be a Unix time"),
        ("/p/p/server/history/list?order=up", 400, "order must be asc or desc"),
        ("/p/p/server/history/job", 400, "uid is required"),
        ("/p/p/server/history/job?uid=FFFFFF", 404, "no run 'FFFFFF'"),
        ("/p/p/server/history/job?uid=job-999999", 404, "no run 'job-999999'"),
        ("/p/p/server/history/job?uid=../x", 404, "no run"),
    ],
)
def test_bad_input_is_refused_in_moonrakers_error_shape(
    farm, runs, path, status, words
):
    answer = farm.client("root").get(path)

    assert answer.status_code == status
    error = answer.json()["error"]
    assert error["code"] == status
    assert words in error["message"]


def test_another_printers_entry_is_not_found_by_uid(farm, runs):
    theirs = HistoryEntry.objects.get(printer=farm.q)

    answer = farm.client("root").get(f"/p/p/server/history/job?uid={theirs.uid}")

    assert answer.status_code == 404


def test_a_caller_without_a_role_on_the_printer_is_refused(farm, runs):
    answer = farm.client("bob").get("/p/p/server/history/list")

    assert answer.status_code == 403
