"""The history page's first render (filters, totals, links) and the admin's history:
listed with its filters and search, never edited."""

from __future__ import annotations

import pytest
from django.contrib.auth import get_user_model
from django.test import Client

from jobs.analysing import analysis_of
from jobs.history import HistoryEntry
from jobs.models import Job

pytestmark = pytest.mark.django_db


@pytest.fixture
def runs(farm):
    first = farm.job(farm.p, "alice")
    cut = analysis_of(first).layers[3].line
    first = farm.end(farm.start(first, minutes_ago=90), "interrupted", acked=cut)
    resumed = farm.end(farm.resume(first, cut, minutes=30), "completed")
    other = farm.run(farm.q, "bob", "failed", message="heater timeout", acked=200)
    return {"first": first, "resumed": resumed, "other": other, "cut": cut}


def page_of(who: str, farm, query: str = "") -> str:
    client = Client()
    client.force_login(farm.users[who])
    answer = client.get(f"/history/{query}")
    assert answer.status_code == 200
    return answer.content.decode()


def test_the_page_lists_the_users_runs_with_totals_links_and_the_csv_link(farm, runs):
    html = page_of("alice", farm)

    assert 'data-test="nav-history" href="/history/"' in html
    assert html.count('data-test="run"') == 2  # p's runs only
    assert f'data-job="{runs["other"].pk}"' not in html
    assert f'<a href="/jobs/{runs["resumed"].pk}/">box.gcode</a>' in html
    assert (
        f"Resumed from line {runs['cut']} of "
        f'<a href="/jobs/{runs["first"].pk}/">#{runs["first"].pk}</a>'
    ) in html
    assert f'Resumed by <a href="/jobs/{runs["resumed"].pk}/">' in html
    assert 'data-test="total-jobs">2<' in html
    assert 'data-test="total-success">50 %<' in html
    assert 'href="/printer/history?format=csv"' in html


def test_the_filters_narrow_the_page_and_the_csv_link_follows_them(farm, runs):
    html = page_of(
        "root", farm, "?printer=q&outcome=failed&since=2020-01-01&until=2099-12-31"
    )

    assert html.count('data-test="run"') == 1
    assert "heater timeout" in html
    assert (
        'href="/printer/history?printer=q&amp;outcome=failed&amp;since=2020-01-01'
        '&amp;before=2100-01-01&amp;format=csv"'
    ) in html


def test_a_bad_filter_shows_the_apis_reason(farm, runs):
    html = page_of("root", farm, "?since=someday")

    assert 'data-test="history-problem"' in html
    assert "since must be an ISO 8601 date" in html


def test_the_last_day_of_the_calendar_is_refused_with_the_apis_reason(farm, runs):
    html = page_of("root", farm, "?until=9999-12-31")

    assert "before must fall in the years 1900 to 2200" in html


def test_a_deleted_jobs_run_has_no_link_to_its_page(farm, runs):
    Job.objects.filter(pk=runs["resumed"].pk).delete()

    html = page_of("alice", farm)

    assert f'href="/jobs/{runs["resumed"].pk}/"' not in html
    assert f"Resumed by #{runs['resumed'].pk}" in html
    assert html.count('data-test="run"') == 2


def test_anonymous_visitors_are_sent_to_the_login_page(farm):
    answer = Client().get("/history/")

    assert answer.status_code == 302
    assert answer["Location"].startswith("/accounts/login/")


@pytest.fixture
def admin_client_(farm) -> Client:
    admin = get_user_model().objects.create_superuser("boss", password="boss")
    client = Client()
    client.force_login(admin)
    return client


def test_the_admin_lists_the_history_with_its_filters_and_search(admin_client_, runs):
    page = admin_client_.get("/admin/jobs/historyentry/").content.decode()
    failed = admin_client_.get("/admin/jobs/historyentry/?outcome=failed")
    found = admin_client_.get("/admin/jobs/historyentry/?q=heater")

    assert "box.gcode" in page
    for title in ("outcome", "printer", "user", "started at"):
        assert f"By {title}" in page
    assert "heater timeout" not in page  # the message is searched, not listed
    assert failed.status_code == 200
    assert failed.context["cl"].result_count == 1
    assert found.context["cl"].result_count == 1


def test_the_admins_history_is_read_only(admin_client_, runs):
    entry = HistoryEntry.objects.first()

    add = admin_client_.get("/admin/jobs/historyentry/add/")
    change = admin_client_.post(
        f"/admin/jobs/historyentry/{entry.pk}/change/", {"name": "edited"}
    )
    delete = admin_client_.post(
        f"/admin/jobs/historyentry/{entry.pk}/delete/", {"post": "yes"}
    )

    assert add.status_code == 403
    assert change.status_code == 403
    assert delete.status_code == 403
    assert HistoryEntry.objects.get(pk=entry.pk).name == "box.gcode"
