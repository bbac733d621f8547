"""A web server whose computer's clock is off judges what other computers stamped
(a host's heartbeat, a job's start) by the database's clock all the same:
printhost/shared_clock.py reads it before a request, at most once a minute.

This process's clock is put an hour ahead (`timezone.now()` and `time.time()`);
the database (SQLite, in-process) keeps the true time, by which the heartbeat and
the job's start are stamped, as a worker host stamps them.
"""

from __future__ import annotations

from datetime import timedelta
from typing import TYPE_CHECKING, Any

import pytest
from asgiref.sync import async_to_sync
from django.contrib.auth import get_user_model
from django.db import connection
from django.http import HttpResponse
from django.test import Client, RequestFactory
from django.test.utils import CaptureQueriesContext

from jobs.models import Job
from printers import dbclock
from printers.hosts import WorkerHost
from printhost.access import issue_key
from printhost.models import PrinterRole, Role
from printhost.shared_clock import learn_clock_offset

if TYPE_CHECKING:
    from collections.abc import Callable

pytestmark = pytest.mark.django_db

HOUR = 3600.0


@pytest.fixture
def viewer_key(db: None) -> str:
    user = get_user_model().objects.create_user("viewer")
    PrinterRole.objects.create(user=user, role=Role.VIEWER, printer=None)
    return issue_key(user, "test")[1]


def get(path: str, key: str) -> dict[str, Any]:
    response = Client().get(path, HTTP_X_API_KEY=key)
    assert response.status_code == 200, response.content
    return response.json()


def clock_reads(queries: CaptureQueriesContext) -> int:
    """Readings of the database's clock (`dbclock.database_now`) among *queries*."""
    asked = f"SELECT {dbclock.now_sql(connection.vendor, with_params=False)}"
    return sum(query["sql"] == asked for query in queries.captured_queries)


def test_a_host_heard_just_now_is_online_on_a_web_server_an_hour_ahead(
    hour_ahead, viewer_key: str
) -> None:
    WorkerHost.objects.create(name="shelf-1", seen_at=dbclock.database_now())
    (host,) = get("/printer/farm", viewer_key)["data"]["hosts"]
    assert host["online"] is True
    assert host["heartbeat_age"] < 30  # not an hour
    assert dbclock.clock_offset() == pytest.approx(-HOUR, abs=1.0)


def test_a_jobs_print_time_is_not_an_hour_longer(
    hour_ahead, viewer_key: str, make_printer: Callable, make_job: Callable
) -> None:
    printer = make_printer(slug="mk3")
    job = make_job(printer, "G28\nG1 X10\n")
    started = dbclock.database_now() - timedelta(seconds=300)
    Job.objects.filter(pk=job.pk).update(state=Job.State.PRINTING, started_at=started)
    body = get("/p/mk3/api/job", viewer_key)
    assert 290 <= body["progress"]["printTime"] <= 400


def test_the_database_clock_is_read_once_a_minute_at_most(
    hour_ahead, viewer_key: str
) -> None:
    with CaptureQueriesContext(connection) as first:
        get("/printer/farm", viewer_key)
    with CaptureQueriesContext(connection) as second:
        get("/printer/farm", viewer_key)
    assert (clock_reads(first), clock_reads(second)) == (1, 0)
    dbclock._learned_at -= dbclock.OFFSET_CHECK_SECONDS
    with CaptureQueriesContext(connection) as later:
        get("/printer/farm", viewer_key)
    assert clock_reads(later) == 1


def test_under_daphne_the_reading_leaves_the_event_loop(hour_ahead) -> None:
    """The async chain: the query runs in a thread (in the loop itself Django
    would refuse it), and the request goes on."""

    async def view(request: Any) -> HttpResponse:
        return HttpResponse("ok")

    middleware = learn_clock_offset(view)
    response = async_to_sync(middleware)(RequestFactory().get("/"))
    assert response.content == b"ok"
    assert dbclock.clock_offset() == pytest.approx(-HOUR, abs=1.0)
