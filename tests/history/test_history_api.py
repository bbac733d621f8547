"""printhost's own history calls: GET /printer/history (JSON and CSV) and
/printer/history/totals, after runs of every outcome, as the worker ends them."""

from __future__ import annotations

import csv
import io
from datetime import timedelta

import pytest
from django.contrib.auth import get_user_model
from django.utils import timezone

from jobs.analysing import analysis_of
from jobs.history import HistoryEntry
from jobs.models import Job
from printhost.access import issue_key

pytestmark = pytest.mark.django_db


@pytest.fixture
def runs(farm):
    """On p: alice completed, aborted, failed, interrupted then resumed it; on q:
    bob completed one. Each started earlier than the next."""
    done = farm.run(farm.p, "alice", "completed", minutes=300)
    aborted = farm.run(farm.p, "alice", "aborted", minutes=250, acked=400)
    failed = farm.run(
        farm.p, "alice", "failed", minutes=200, acked=300, message="thermal runaway"
    )
    cut = analysis_of(done).layers[5].line
    interrupted = farm.run(farm.p, "alice", "interrupted", minutes=150, acked=cut)
    resumed = farm.end(farm.resume(interrupted, cut, minutes=100), "completed")
    other = farm.run(farm.q, "bob", "completed", minutes=50, name="other.gcode")
    return {
        "done": done,
        "aborted": aborted,
        "failed": failed,
        "interrupted": interrupted,
        "resumed": resumed,
        "other": other,
    }


def listed(client, query: str = "") -> dict:
    answer = client.get(f"/printer/history{query}")
    assert answer.status_code == 200, answer.content
    body = answer.json()
    assert body["error"] == ""
    return body["data"]


def test_the_list_holds_every_run_newest_first_with_its_outcome(farm, runs):
    data = listed(farm.client("root"))

    assert data["count"] == 6
    assert [(r["job"], r["outcome"]) for r in data["runs"]] == [
        (runs["other"].pk, "completed"),
        (runs["resumed"].pk, "completed"),
        (runs["interrupted"].pk, "interrupted"),
        (runs["failed"].pk, "failed"),
        (runs["aborted"].pk, "aborted"),
        (runs["done"].pk, "completed"),
    ]
    failed = data["runs"][3]
    assert failed["message"] == "thermal runaway"
    assert (failed["printer"], failed["user"], failed["origin"]) == (
        "p",
        "alice",
        "http:alice key",
    )
    assert failed["name"] == "box.gcode" and len(failed["sha256"]) == 64
    assert failed["print_seconds"] == pytest.approx(200 * 60, abs=5)
    assert failed["finished"] is not None and failed["job_exists"] is True


def test_a_resumed_run_says_which_run_and_line_it_resumed_and_is_named_back(farm, runs):
    data = listed(farm.client("alice"), "?printer=p")
    by_job = {r["job"]: r for r in data["runs"]}
    resumed = by_job[runs["resumed"].pk]
    interrupted = by_job[runs["interrupted"].pk]

    assert resumed["resumed_from"] == {
        "job": runs["interrupted"].pk,
        "line": runs["resumed"].start_line,
        "exists": True,
    }
    assert resumed["start_line"] > 0
    assert interrupted["resumed_by"] == [{"job": runs["resumed"].pk, "exists": True}]
    assert (resumed["layer"], resumed["layers"]) == (10, 10)
    assert interrupted["layer"] == 6


@pytest.mark.parametrize(
    ("query", "expected"),
    [
        ("?outcome=completed", ["other", "resumed", "done"]),
        ("?outcome=aborted", ["aborted"]),
        ("?outcome=failed", ["failed"]),
        ("?outcome=interrupted", ["interrupted"]),
        ("?outcome=resumed", ["resumed"]),
        ("?printer=q", ["other"]),
        ("?user=bob", ["other"]),
        ("?user=alice&outcome=completed", ["resumed", "done"]),
        ("?order=asc&limit=2", ["done", "aborted"]),
        ("?limit=2&offset=2", ["interrupted", "failed"]),
    ],
)
def test_filters_pick_the_runs(farm, runs, query, expected):
    data = listed(farm.client("root"), query)

    assert [r["job"] for r in data["runs"]] == [runs[name].pk for name in expected]


def test_a_period_filters_on_the_start_time(farm, runs):
    now = timezone.now()
    since = (now - timedelta(minutes=220)).isoformat()
    before = (now - timedelta(minutes=120)).isoformat()
    client = farm.client("root")

    data = listed(client, "?" + _query(since=since, before=before))

    assert [r["job"] for r in data["runs"]] == [
        runs["interrupted"].pk,
        runs["failed"].pk,
    ]
    # A date alone is its midnight.
    yesterday = (timezone.localdate() - timedelta(days=1)).isoformat()
    assert listed(client, f"?since={yesterday}")["count"] == 6
    tomorrow = (timezone.localdate() + timedelta(days=1)).isoformat()
    assert listed(client, f"?since={tomorrow}")["count"] == 0


def _query(**params: str) -> str:
    from urllib.parse import urlencode

    return urlencode(params)


def test_a_running_run_is_listed_live_in_its_place(farm, runs):
    job = farm.start(farm.job(farm.p, "alice", name="live.gcode"), minutes_ago=75)
    Job.objects.filter(pk=job.pk).update(lines_acked=analysis_of(job).layers[2].line)
    client = farm.client("root")

    data = listed(client)

    assert data["count"] == 7
    names = [(r["job"], r["outcome"]) for r in data["runs"]]
    assert names[:3] == [
        (runs["other"].pk, "completed"),  # started 50 minutes ago
        (job.pk, "in_progress"),  # 75
        (runs["resumed"].pk, "completed"),  # 100
    ]
    live = data["runs"][1]
    assert live["finished"] is None and live["layer"] == 3
    assert live["filament_used"] > 0
    # Pages around it: every run once, none twice.
    pages = [
        listed(client, f"?limit=2&offset={start}")["runs"] for start in (0, 2, 4, 6)
    ]
    assert [r["job"] for page in pages for r in page] == [job for job, _ in names]
    assert [r["job"] for r in listed(client, "?outcome=in_progress")["runs"]] == [
        job.pk
    ]


def test_each_caller_reads_only_the_printers_it_may_view(farm, runs):
    vera = listed(farm.client("vera"))
    bob = listed(farm.client("bob"))

    assert {r["printer"] for r in vera["runs"]} == {"p"}
    assert vera["count"] == 5
    assert [r["job"] for r in bob["runs"]] == [runs["other"].pk]
    answer = farm.client("bob").get("/printer/history?printer=p")
    assert answer.status_code == 403
    assert "viewer role needed" in answer.json()["error"]


@pytest.mark.parametrize(
    ("query", "status", "words"),
    [
        ("?printer=nope", 404, "Unknown printer 'nope'"),
        ("?since=yesterday", 400, "since must be an ISO 8601 date"),
        ("?before=2026-13-40", 400, "before must be an ISO 8601 date"),
        ("?since=2026-11-02&before=2026-11-01", 400, "before must be later"),
        # In UTC these fall off the calendar (OverflowError: a 500 before).
        (
            "?since=0001-01-01T00:00:00%2B05:00",
            400,
            "since must fall in the years 1900 to 2200",
        ),
        (
            "/totals?before=9999-12-31T23:59:59-05:00",
            400,
            "before must fall in the years 1900 to 2200",
        ),
        ("?limit=-1", 400, "limit must be 0 or more"),
        ("?limit=5000", 400, "limit must be at most 1000"),
        ("?offset=x", 400, "offset must be an integer"),
        ("?outcome=exploded", 400, "outcome must be one of"),
        ("?order=sideways", 400, "order must be asc or desc"),
        ("?format=xml", 400, "format must be json or csv"),
        ("/totals?group=colour", 400, "group must be one of printer, user, file"),
        ("/totals?outcome=failed", 400, "totals count every outcome"),
    ],
)
def test_bad_input_is_refused_with_a_reason(farm, runs, query, status, words):
    answer = farm.client("root").get(f"/printer/history{query}")

    assert answer.status_code == status
    assert words in answer.json()["error"]


def test_anonymous_callers_are_refused(farm):
    from django.test import Client

    assert Client().get("/printer/history").status_code == 401


def totals(client, query: str) -> dict:
    answer = client.get(f"/printer/history/totals{query}")
    assert answer.status_code == 200, answer.content
    return answer.json()["data"]


@pytest.mark.parametrize("group", ["printer", "user", "file"])
def test_totals_by_group_add_up_to_the_overall_totals(farm, runs, group):
    data = totals(farm.client("root"), f"?group={group}")
    overall, groups = data["overall"], data["groups"]

    entries = list(HistoryEntry.objects.all())
    assert overall["jobs"] == len(entries) == 6
    assert overall["completed"] == 3
    assert overall["success_rate"] == 0.5
    seconds = sum(e.print_seconds for e in entries)
    assert overall["print_seconds"] == pytest.approx(seconds, abs=0.1)
    assert overall["print_hours"] == pytest.approx(seconds / 3600, abs=0.01)
    filament = sum(e.filament_used for e in entries)
    assert overall["filament_used"] == pytest.approx(filament, abs=0.1)
    assert sum(g["jobs"] for g in groups) == overall["jobs"]
    assert sum(g["completed"] for g in groups) == overall["completed"]
    assert sum(g["print_seconds"] for g in groups) == pytest.approx(
        overall["print_seconds"], abs=0.2
    )
    assert sum(g["filament_used"] for g in groups) == pytest.approx(
        overall["filament_used"], abs=0.2
    )


def test_totals_per_printer_user_and_file_count_their_own_runs(farm, runs):
    client = farm.client("root")

    printers = {g["key"]: g for g in totals(client, "?group=printer")["groups"]}
    users = {g["key"]: g for g in totals(client, "?group=user")["groups"]}
    files = totals(client, "?group=file")["groups"]

    assert (printers["p"]["jobs"], printers["p"]["completed"]) == (5, 2)
    assert printers["p"]["success_rate"] == 0.4
    assert (printers["q"]["jobs"], printers["q"]["success_rate"]) == (1, 1.0)
    assert printers["q"]["label"] == "Prusa Q"
    assert (users["alice"]["jobs"], users["bob"]["jobs"]) == (5, 1)
    # Every run printed the same file (same SHA-256), under two names.
    assert len(files) == 1 and files[0]["jobs"] == 6
    assert files[0]["key"] == runs["done"].sha256


def test_totals_over_a_period_and_a_printer(farm, runs):
    since = (timezone.now() - timedelta(minutes=120)).isoformat()
    client = farm.client("root")

    data = totals(client, "?" + _query(since=since, printer="p"))

    assert data["overall"]["jobs"] == 1  # the resumed run, started 100 minutes ago
    assert data["since"] is not None and data["before"] is None
    empty = totals(client, "?printer=q&user=alice")["overall"]
    assert (empty["jobs"], empty["success_rate"]) == (0, None)


#: The test client reads the export's async stream at once (daphne sends it as it
#: comes); Django warns that it must.
SYNC_READ = pytest.mark.filterwarnings(
    "ignore:StreamingHttpResponse must consume asynchronous iterators"
)


@SYNC_READ
def test_csv_export_is_an_attachment_with_a_row_per_run(farm, runs):
    answer = farm.client("alice").get("/printer/history?format=csv&printer=p")

    assert answer.status_code == 200
    assert answer["Content-Type"].startswith("text/csv")
    assert answer["Content-Disposition"].startswith(
        'attachment; filename="printhost-history-'
    )
    assert answer.streaming, "an export is written as it is read, not held whole"
    rows = list(csv.DictReader(io.StringIO(b"".join(answer).decode())))
    assert len(rows) == 5
    by_job = {int(r["job"]): r for r in rows}
    resumed = by_job[runs["resumed"].pk]
    assert resumed["outcome"] == "completed"
    assert resumed["resumed_from_job"] == str(runs["interrupted"].pk)
    assert int(resumed["resumed_from_line"]) == runs["resumed"].start_line
    assert by_job[runs["failed"].pk]["message"] == "thermal runaway"
    assert float(by_job[runs["done"].pk]["filament_used_mm"]) > 100


@SYNC_READ
def test_csv_keeps_a_file_name_that_looks_like_a_formula_as_text(farm):
    job = farm.run(farm.p, "alice", "completed")
    HistoryEntry.objects.filter(job_number=job.pk).update(name="=cmd|' /C calc'!A0")

    answer = farm.client("alice").get("/printer/history?format=csv")

    rows = list(csv.DictReader(io.StringIO(b"".join(answer).decode())))
    assert rows[0]["name"] == "'=cmd|' /C calc'!A0"


@pytest.mark.django_db(transaction=True)
def test_csv_export_is_sent_as_it_is_read_under_asgi(make_printer, monkeypatch) -> None:
    """Through the ASGI application daphne serves: the export's first rows go out
    before its last are read (a batch of 500 runs at a time), not read whole first."""
    import asyncio

    from asgiref.testing import ApplicationCommunicator

    from printhost.api import print_history
    from printhost.asgi import http_application

    read = [0]
    runs = print_history.iter_runs

    def counted(query):
        for run in runs(query):
            read[0] += 1
            yield run

    monkeypatch.setattr(print_history, "iter_runs", counted)

    printer = make_printer(slug="p")
    root = get_user_model().objects.create_superuser("root", password="x")
    key = issue_key(root, "export")[1]
    now = timezone.now()
    HistoryEntry.objects.bulk_create(
        HistoryEntry(
            job_number=n, printer=printer, name=f"run {n}.gcode", started_at=now,
            finished_at=now, outcome="completed",
        )
        for n in range(1, 1201)
    )  # fmt: skip

    async def export() -> list[bytes]:
        scope = {
            "type": "http", "method": "GET", "path": "/printer/history",
            "query_string": b"format=csv", "headers": [(b"x-api-key", key.encode())],
            "server": ("testserver", 80), "client": ("127.0.0.1", 5000),
            "scheme": "http", "http_version": "1.1", "root_path": "",
        }  # fmt: skip
        app = ApplicationCommunicator(http_application, scope)
        await app.send_input({"type": "http.request", "body": b""})
        start = await app.receive_output(30)
        assert start["status"] == 200, start
        bodies = [(await app.receive_output(30))["body"]]
        assert read[0] < 1200, "every run was read before the first was sent"
        while True:
            message = await app.receive_output(30)
            bodies.append(message.get("body", b""))
            if not message.get("more_body"):
                return bodies

    bodies = asyncio.run(export())
    rows = list(csv.DictReader(io.StringIO(b"".join(bodies).decode())))
    assert len(rows) == 1200


def test_a_caller_with_a_role_everywhere_is_not_matched_against_a_printer_list(farm):
    """An OR of the list and the deleted printers' runs made the database sort
    every run for each page; such a caller may read every printer anyway."""
    from printhost.access import Caller
    from printhost.api.print_history import query_from

    everywhere = Caller(client="test", user=farm.users["root"])
    one = Caller(client="test", user=farm.users["alice"])
    assert query_from(everywhere, {}).printer_ids is None
    assert query_from(one, {}).printer_ids == frozenset({farm.p.pk})
