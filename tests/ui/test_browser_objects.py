"""Cancel an object from the job page in real Chromium: a confirm, then the object
shows as cancelled and the preview greys it (runhost's Celery worker analyses)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from tests.conftest import wait_for
from tests.ui.conftest import (
    OPERATOR,
    PRINT_MS,
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
SLUG = "mk-objects"
THREE = Path(__file__).parents[1] / "data" / "prusaslicer-2.5_three-boxes.gcode"


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveHost]:
    folder = tmp_path_factory.mktemp("browser-objects")
    # The heater waits out (M109, M190 become M104, M140): the print starts at once.
    text = re.sub(r"^M109 ", "M104 ", THREE.read_text(), flags=re.M)
    text = re.sub(r"^M190 ", "M140 ", text, flags=re.M)
    yield from start_live_host(
        folder, {SLUG: "--time-scale 0.5"}, jobs={SLUG: text}, celery=True
    )


def test_an_operator_cancels_an_object_from_the_job_page(
    live: LiveHost, open_tab: Callable[..., Tab]
) -> None:
    wait_for(
        lambda: live.host.query("SELECT state FROM jobs_fileanalysis") == [("done",)],
        60, "runhost's Celery worker to analyse the job",
    )  # fmt: skip
    wait_for(
        lambda: live.host.query("SELECT state FROM jobs_job") == [("printing",)],
        PRINT_MS / 1000, "the job to print",
    )  # fmt: skip
    job_id = live.job_ids(SLUG)[0]
    tab = open_tab(live.url, "phone")
    page = tab.page
    log_in(tab, OPERATOR)
    tab.go(f"/jobs/{job_id}/")
    box_b = page.locator("[data-test=object][data-name='box-b.stl']")
    asked: list[str] = []

    def accept(dialog) -> None:
        asked.append(dialog.message)
        dialog.accept()

    page.on("dialog", accept)
    box_b.locator("[data-test=cancel-object]").click()
    expect(box_b).to_have_attribute("data-cancelled", "true")
    expect(box_b.locator("[data-test=object-cancelled]")).to_be_visible()
    assert asked and "box-b.stl" in asked[0]
    preview = page.locator("[data-test=preview]")
    expect(preview).to_have_attribute(
        "data-cancelled-drawn", re.compile(r"^[1-9]\d*$"), timeout=PRINT_MS
    )
    tab.screenshot("job-objects-cancelled", top="objects")
    assert live.host.query("SELECT cancelled_objects FROM jobs_job") == [
        ('["box-b.stl"]',)
    ]
    assert not tab.unexpected_errors()
