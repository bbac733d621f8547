"""The resume page in real Chromium, with a real Celery worker making the plan: an
operator picks a layer, reads the preamble, starts the resumed run; the screenshots
the README shows are taken at phone and tablet size."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from tests.conftest import wait_for
from tests.resume.prints import layered_print
from tests.ui.conftest import (
    OPERATOR,
    VIEWPORTS,
    LiveHost,
    Tab,
    log_in,
    playwright_api,
    start_live_host,
)

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

pytestmark = pytest.mark.slow

expect = playwright_api().expect

SLUG = "mk3"


@pytest.fixture(scope="module")
def stopped(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveHost]:
    """An offline printer whose job, analysed by the Celery worker, was interrupted."""
    folder = tmp_path_factory.mktemp("browser-resume")
    hosts = start_live_host(
        folder, {SLUG: ""}, jobs={SLUG: layered_print()}, celery=True
    )
    live = next(hosts)
    wait_for(
        lambda: live.host.query("SELECT state FROM jobs_fileanalysis")[0][0] == "done",
        120, "the Celery worker to analyse the file",
    )  # fmt: skip
    live.host.shell(
        "from jobs.models import Job; Job.objects.update(state='interrupted', "
        "lines_acked=500, message='interrupted: the worker stopped at line 500')"
    )
    yield live
    hosts.close()


@pytest.mark.parametrize("size", list(VIEWPORTS))
def test_an_operator_previews_a_layer_resume_and_starts_it(
    size: str, stopped: LiveHost, open_tab: Callable[..., Tab]
) -> None:
    (job,) = stopped.job_ids(SLUG)[:1]
    tab = open_tab(stopped.url, size)
    log_in(tab, OPERATOR, f"/jobs/{job}/")
    page = tab.page
    page.locator("[data-test=resume-link]").click()
    page.wait_for_url(f"**/jobs/{job}/resume/")

    page.locator("input[name=from][value=layer]").check()
    page.select_option("[data-test=resume-layer]", "2")
    page.locator("[data-test=resume-preview]").click()
    state = page.locator("[data-test=resume-plan-state]")
    expect(state).to_have_text("Resume at layer 3 (line 262): ready", timeout=60_000)
    preamble = page.locator("[data-test=resume-preamble]")
    expect(preamble).to_contain_text("G28 X Y ; home X and Y only")
    expect(page.locator("[data-test=resume-warnings] li")).to_have_count(1)
    width = page.evaluate("() => [document.documentElement.scrollWidth, innerWidth]")
    assert width[0] <= width[1], "the page scrolls sideways"
    tab.screenshot("resume", top="resume-plan")

    if size == "tablet":  # start it once (the plan is used up)
        page.once("dialog", lambda dialog: dialog.accept())
        page.locator("[data-test=resume-start]").click()
        page.wait_for_url("**/jobs/*/")
        expect(page.locator("[data-test=resumed-from]")).to_have_text(
            f"Resumed at line 262 of run #{job}."
        )
        rows = stopped.host.query(
            "SELECT state, start_line, resume_of_id FROM jobs_job ORDER BY id"
        )
        assert rows[-1] == ("queued", 262, job)
    assert not tab.unexpected_errors()
