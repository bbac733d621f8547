"""A printer's job list (`/printer/job/<slug>?a=list`, Repetier's `listJobs`): its
open jobs in queue order, then its newest finished ones, never its whole history."""

from __future__ import annotations

import json
from datetime import timedelta

from django.test import Client
from django.utils import timezone

from jobs.listing import FINISHED_MOST, FINISHED_SHOWN
from jobs.models import Job
from tests.api.printer_api_helpers import GCODE, call


def _history(printer, make_job, finished: int) -> tuple[list[int], list[int]]:
    """Two queued jobs and *finished* finished ones, ended a minute apart, the
    highest id the oldest end. Returns (queued ids in order, finished newest first)."""
    queued = [make_job(printer, GCODE).pk for _ in range(2)]
    model = Job.objects.get(pk=queued[0])
    start = timezone.now() - timedelta(days=1)
    ended = []
    for n in range(finished):
        model.pk = None
        model.state = Job.State.COMPLETED
        model.finished_at = start - timedelta(minutes=n)
        model.save()
        ended.append(model.pk)
    return queued, ended


def test_list_gives_open_jobs_then_the_newest_finished(keys, printer, make_job):
    queued, ended = _history(printer, make_job, FINISHED_SHOWN + 10)
    status, body = call("get", "/printer/job/mk3?a=list", keys("viewer"))
    assert status == 200, body
    ids = [job["id"] for job in body["data"]]
    assert ids == queued + ended[:FINISHED_SHOWN]


def test_list_gives_as_many_finished_as_asked(keys, printer, make_job):
    queued, ended = _history(printer, make_job, 5)
    key = keys("viewer")
    _, body = call("get", "/printer/job/mk3?a=list&finished=2", key)
    assert [job["id"] for job in body["data"]] == queued + ended[:2]
    _, body = call("get", "/printer/job/mk3?a=list&finished=0", key)
    assert [job["id"] for job in body["data"]] == queued


def test_list_refuses_a_bad_finished_count(keys, printer):
    key = keys("viewer")
    for value, words in (
        ("lots", "must be an integer"),
        ("-1", "0 or more"),
        (str(FINISHED_MOST + 1), f"{FINISHED_MOST} or less"),
    ):
        status, body = call("get", f"/printer/job/mk3?a=list&finished={value}", key)
        assert status == 400
        assert words in body["error"]


def test_repetier_list_jobs_is_bounded_the_same_way(keys, printer, make_job):
    queued, ended = _history(printer, make_job, 3)
    client = Client(HTTP_X_API_KEY=keys("viewer"))
    answer = client.get("/printer/api/mk3", {"a": "listJobs"})
    assert [job["id"] for job in json.loads(answer.content)["data"]] == queued + ended
    answer = client.get(
        "/printer/api/mk3", {"a": "listJobs", "data": json.dumps({"finished": 1})}
    )
    assert [job["id"] for job in json.loads(answer.content)["data"]] == [
        *queued,
        ended[0],
    ]
    answer = client.get(
        "/printer/api/mk3", {"a": "listJobs", "data": json.dumps({"finished": "x"})}
    )
    assert answer.status_code == 400
