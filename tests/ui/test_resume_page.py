"""The resume page: the choices it offers, and who may preview and start."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import pytest

from jobs.analysis_task import run as analyse
from jobs.models import Job
from printhost.models import Role
from tests.resume.prints import layered_print
from tests.ui.test_pages import user_with

if TYPE_CHECKING:
    from collections.abc import Callable

    from django.test import Client

    from printers.models import Printer


@pytest.fixture
def stopped(make_printer: Callable[..., Printer], make_job: Callable[..., Any]) -> Job:
    printer = make_printer(name="Prusa", slug="prusa", state="idle")
    job = make_job(printer, layered_print(layers=3, per_layer=10), name="cube.gcode")
    analyse(job.analysis_id)
    Job.objects.filter(pk=job.pk).update(state=Job.State.INTERRUPTED, lines_acked=25)
    return job


def test_the_page_offers_the_last_line_and_every_layer_to_an_operator(
    client: Client, stopped: Job
) -> None:
    client.force_login(user_with(Role.OPERATOR, stopped.printer))
    page = client.get(f"/jobs/{stopped.pk}/resume/").content.decode()
    assert "After the last acknowledged line (25 of" in page
    assert page.count("<option value=") == 3 and "Z 0.60 mm" in page
    assert 'data-test="resume-preview"' in page


def test_a_viewer_reads_the_page_without_the_buttons(
    client: Client, stopped: Job
) -> None:
    client.force_login(user_with(Role.VIEWER, stopped.printer))
    response = client.get(f"/jobs/{stopped.pk}/resume/")
    assert response.status_code == 200
    assert b'data-test="resume-preview"' not in response.content
    assert b'data-test="resume-start"' not in response.content


def test_someone_without_a_role_on_the_printer_is_refused(
    client: Client, stopped: Job
) -> None:
    client.force_login(user_with(None))
    assert client.get(f"/jobs/{stopped.pk}/resume/").status_code == 403


def test_a_stopped_jobs_page_links_to_its_resume_page(
    client: Client, stopped: Job
) -> None:
    client.force_login(user_with(Role.VIEWER, stopped.printer))
    page = client.get(f"/jobs/{stopped.pk}/").content.decode()
    assert f'href="/jobs/{stopped.pk}/resume/"' in page
    Job.objects.filter(pk=stopped.pk).update(state=Job.State.COMPLETED)
    page = client.get(f"/jobs/{stopped.pk}/").content.decode()
    assert "/resume/" not in page
