"""Analyses in the Django admin: their state on jobs, their own list, analyse again."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest
from django.core.exceptions import ValidationError
from django.test import Client

from jobs import analysis_task
from jobs.models import FileAnalysis
from printers.models import Printer

if TYPE_CHECKING:
    from collections.abc import Callable

SQUARE = "G28\nM83\nG1 Z0.2 F600\nG1 X10 E1 F1200\nG1 Y10 E1\n"


@pytest.fixture
def admin_client_(db: None, django_user_model: type) -> Client:
    django_user_model.objects.create_superuser("boss", password="boss")
    client = Client()
    client.login(username="boss", password="boss")
    return client


def test_the_job_list_shows_each_files_analysis(
    admin_client_: Client, make_printer: Callable, make_job: Callable
) -> None:
    printer = make_printer(slug="mk3")
    done = make_job(printer, SQUARE, name="done.gcode")
    analysis_task.run(done.analysis_id)
    make_job(printer, SQUARE + "G1 X0\n", name="waiting.gcode")
    page = admin_client_.get("/admin/jobs/job/").content.decode()
    assert "waiting for a Celery worker" in page
    assert " min" in page  # the done one shows its estimate


def test_a_failed_analysis_is_listed_with_its_reason_and_sent_again(
    admin_client_: Client, make_printer: Callable, make_job: Callable,
    monkeypatch: pytest.MonkeyPatch,
) -> None:  # fmt: skip
    sent: list[int] = []
    monkeypatch.setattr("jobs.tasks.analyse_file.delay", sent.append)
    job = make_job(make_printer(slug="mk3"), SQUARE)
    FileAnalysis.objects.filter(pk=job.analysis_id).update(
        state=FileAnalysis.State.FAILED, reason="OSError: disk gone"
    )
    page = admin_client_.get("/admin/jobs/fileanalysis/?state=failed").content.decode()
    assert "OSError: disk gone" in page
    answer = admin_client_.post(
        "/admin/jobs/fileanalysis/",
        {"action": "analyse_again", "_selected_action": [job.analysis_id]},
    )
    assert answer.status_code == 302
    assert sent == [job.analysis_id]
    assert FileAnalysis.objects.get(pk=job.analysis_id).state == "pending"


def test_the_printer_form_takes_a_motion_profile_and_refuses_a_bad_one(
    admin_client_: Client, make_printer: Callable
) -> None:
    printer = make_printer(slug="mk3")
    page = admin_client_.get(f"/admin/printers/printer/{printer.pk}/change/")
    assert b"motion_profile" in page.content
    field = Printer._meta.get_field("motion_profile")
    with pytest.raises(ValidationError, match="four numbers"):
        field.run_validators({"jerk": [1, 2]})
    with pytest.raises(ValidationError, match="an object"):
        field.run_validators([1, 2])
    field.run_validators({"classic_jerk": True, "jerk": [8, 8, 0.4, 2]})
