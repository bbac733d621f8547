"""What the views hosts and dashboards poll cost in queries: `/printer/state/<slug>`
a fixed four (key, roles, printer, its jobs), `/printer/list` a fixed four however
many printers there are, and the key read once per call.

A farm's API load asks these tens of times a second (bench/farm.py); a query a
printer or a job would grow with the farm. (The farm view's count is pinned in
tests/farm/test_farm_view_queries.py.)
"""

from __future__ import annotations

import json
from datetime import timedelta
from typing import TYPE_CHECKING, Any

import pytest
from django.contrib.auth import get_user_model
from django.db import connection
from django.test import Client
from django.test.utils import CaptureQueriesContext
from django.utils import timezone

from jobs.analysis_task import run
from jobs.models import Job, running_job
from printers.models import Printer
from printhost.access import issue_key
from printhost.models import PrinterRole, Role
from tests.farm.conftest import box_gcode

if TYPE_CHECKING:
    from collections.abc import Callable

pytestmark = pytest.mark.django_db

PART = box_gcode(40, 30, 10)
#: Key, roles, printer, the printer's running and queued jobs.
STATE_QUERIES = 4
#: Key, roles, printers, their running jobs' states.
LIST_QUERIES = 4


def get(path: str, key: str) -> dict[str, Any]:
    response = Client().get(path, HTTP_X_API_KEY=key)
    assert response.status_code == 200, response.content
    return json.loads(response.content)


def busy(printer: Printer, make_job: Callable[..., Job], queued: int) -> Job:
    """Give *printer* a running job (its file analysed) and *queued* more."""
    running = make_job(printer, PART)
    assert run(running.analysis_id, worker="test") in ("done", "skipped")
    Job.objects.filter(pk=running.pk).update(
        state=Job.State.PRINTING,
        started_at=timezone.now() - timedelta(seconds=30),
        bytes_acked=running.size_bytes // 3,
    )
    for _ in range(queued):
        make_job(printer, PART)
    return running


def test_a_printers_state_costs_the_same_queries_for_a_queue_of_one_or_ten(
    keys: Callable[..., str],
    printer: Printer,
    make_job: Callable[..., Job],
    django_assert_num_queries: Callable[..., Any],
) -> None:
    key = keys("viewer")
    busy(printer, make_job, queued=1)
    # The first call of a process reads the running file's analysis (its result
    # is kept per process, jobs.analysing.analysis_of): not what a poll costs.
    get("/printer/state/mk3", key)
    with django_assert_num_queries(STATE_QUERIES):
        one = get("/printer/state/mk3", key)["data"]
    for _ in range(9):
        make_job(printer, PART)
    with django_assert_num_queries(STATE_QUERIES):
        ten = get("/printer/state/mk3", key)["data"]

    assert one["job"]["id"] == ten["job"]["id"]
    assert one["job"]["analysis"]["state"] == "done"
    assert (len(one["queue"]), len(ten["queue"])) == (1, 10)


def test_a_printers_state_shows_the_job_running_job_finds_and_the_queue_in_order(
    keys: Callable[..., str], printer: Printer, make_job: Callable[..., Job]
) -> None:
    """One read gives both: the earliest started of the running jobs (as
    `running_job`, even if a stale row says two run) and the queue by position."""
    later = busy(printer, make_job, queued=0)
    earlier = busy(printer, make_job, queued=0)
    Job.objects.filter(pk=earlier.pk).update(
        state=Job.State.PAUSED, started_at=timezone.now() - timedelta(minutes=5)
    )
    first, second, third = (make_job(printer, PART) for _ in range(3))
    Job.objects.filter(pk=third.pk).update(position=first.position - 1)

    data = get("/printer/state/mk3", keys("viewer"))["data"]

    assert running_job(printer.pk) == earlier != later
    assert data["job"]["id"] == earlier.pk and data["job"]["state"] == "paused"
    assert data["job"]["printer"] == "mk3"
    assert [job["id"] for job in data["queue"]] == [third.pk, first.pk, second.pk]


def test_the_printer_list_costs_the_same_queries_for_two_printers_or_ten(
    make_printer: Callable[..., Printer],
    make_job: Callable[..., Job],
    django_assert_num_queries: Callable[..., Any],
) -> None:
    """A viewer with a role on some printers only: each printer's role comes from
    one read of the user's roles, not one query a printer."""
    user = get_user_model().objects.create_user("watcher")
    key = issue_key(user, "test")[1]

    def add(slug: str, *, seen: bool) -> None:
        printer = make_printer(slug=slug, state=Printer.State.PRINTING)
        busy(printer, make_job, queued=1)
        if seen:
            PrinterRole.objects.create(user=user, printer=printer, role=Role.VIEWER)

    for n in range(2):
        add(f"a{n}", seen=True)
    add("hidden0", seen=False)
    get("/printer/list", key)  # stamps the key's first use (then once a minute)
    with django_assert_num_queries(LIST_QUERIES):
        two = get("/printer/list", key)["data"]
    for n in range(2, 10):
        add(f"a{n}", seen=True)
    add("hidden1", seen=False)
    with django_assert_num_queries(LIST_QUERIES):
        ten = get("/printer/list", key)["data"]

    assert [p["slug"] for p in two] == ["a0", "a1"]
    assert [p["slug"] for p in ten] == [f"a{n}" for n in range(10)]
    assert {p["job"] for p in ten} == {"printing"}


def test_an_api_call_reads_its_key_once(
    keys: Callable[..., str], printer: Printer
) -> None:
    key = keys("viewer")
    get("/printer/list", key)  # stamps the key's last use (at most once a minute)
    for path in ("/printer/state/mk3", "/printer/list"):
        with CaptureQueriesContext(connection) as queries:
            get(path, key)
        reads = [q for q in queries.captured_queries if "printhost_apikey" in q["sql"]]
        assert len(reads) == 1, path
