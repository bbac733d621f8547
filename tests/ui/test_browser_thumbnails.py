"""Analysis in real Chromium: the slicer's picture on the dashboard card and in the
queue, and the live layer, ETA and end time of a print (runhost's own Celery
worker analyses the files; nothing here runs the analysis by hand)."""

from __future__ import annotations

import base64
import re
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from jobs.analysis.thumbnails import png_encode
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

SLUG = "mk-pic"
PRUSA = (
    Path(__file__).resolve().parent.parent
    / "data"
    / "prusaslicer-2.5_box-and-cylinder.gcode"
)


def without_waits(text: str) -> str:
    """The heater waits out (M190, M109 become M140, M104): the first layer starts
    at once, so the test sees a layer number within its time."""
    return re.sub(
        r"^M190 ", "M140 ", re.sub(r"^M109 ", "M104 ", text, flags=re.M), flags=re.M
    )


def with_thumbnail(text: str) -> str:
    picture = base64.b64encode(png_encode(96, 96, bytes([40, 160, 90, 255]) * 96 * 96))
    block = f"; thumbnail begin 96x96 {len(picture)}\n; {picture.decode()}\n; thumbnail end\n"
    return block + text


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveHost]:
    folder = tmp_path_factory.mktemp("browser-pictures")
    # Moves take a fifth of their real time: the print runs for minutes.
    yield from start_live_host(
        folder,
        {SLUG: "--time-scale 0.2"},
        jobs={SLUG: with_thumbnail(without_waits(PRUSA.read_text()))},
        celery=True,
    )


def test_the_printing_cards_picture_layer_and_end_time_come_from_the_analysis(
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
    second = live.folder / "second.gcode"
    second.write_text(with_thumbnail(PRUSA.read_text().replace("M107", "M107 ; 2", 1)))
    live.host.manage("add_job", SLUG, str(second), "--name", "second.gcode")

    tab = open_tab(live.url, "phone")
    page = tab.page
    log_in(tab, OPERATOR)
    card = page.locator(f"[data-test=printer-card][data-printer={SLUG}]")
    picture = card.locator("[data-test=thumbnail]")
    expect(picture).to_be_visible(timeout=PRINT_MS)
    expect(picture).to_have_attribute(
        "src", re.compile(r"/printer/thumbnail/mk-pic/\d+/96x96\.png")
    )
    assert page.evaluate("el => el.naturalWidth", picture.element_handle()) == 96
    expect(card.locator("[data-test=layer]")).to_have_text(
        re.compile(r"^\d+ / 50$"), timeout=PRINT_MS
    )
    expect(card.locator("[data-test=ends-at]")).to_have_text(re.compile(r"\d\d:\d\d"))

    page.goto(f"{live.url}/printers/{SLUG}/")
    row = page.locator("[data-test=queue-job]").filter(has_text="second.gcode")
    expect(row.locator("[data-test=queue-job-thumbnail]")).to_be_visible(
        timeout=PRINT_MS
    )
    expect(row.locator("[data-test=queue-job-analysis]")).to_contain_text("50 layers")

    row.locator("a.name").click()
    panel = page.locator("[data-test=analysis]")
    expect(panel).to_have_attribute("data-state", "done", timeout=PRINT_MS)
    expect(panel.locator("[data-test=analysis-layers]")).to_have_text(
        "50 \u00d7 0.2 mm"
    )
    expect(panel.locator("[data-test=analysis-time]")).to_have_text(
        re.compile(r"^1[5-9]:\d\d$")
    )
    expect(panel.locator("[data-test=analysis-thumbnail]")).to_be_visible()
    assert tab.unexpected_errors() == []
