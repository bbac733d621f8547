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
    # The src is set before the picture has loaded: its width is 0 until then.
    loaded = "el => el.complete && el.naturalWidth > 0"
    page.wait_for_function(loaded, arg=picture.element_handle(), timeout=PRINT_MS)
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


def first_load_bytes(tab: Tab, path: str) -> int:
    """Bytes of every response a first visit to *path* fetches (a fresh context: no
    cache), until the network is quiet."""
    sizes: list[int] = []

    def on_response(response) -> None:
        try:
            sizes.append(len(response.body()))
        except Exception:
            sizes.append(0)

    tab.page.on("response", on_response)
    tab.page.goto(tab.base + path, wait_until="networkidle")
    tab.page.remove_listener("response", on_response)
    return sum(sizes)


@pytest.mark.parametrize("size", ["phone", "tablet"])
def test_the_preview_draws_layers_follows_the_print_and_stays_light(
    live: LiveHost, open_tab: Callable[..., Tab], size: str
) -> None:
    wait_for(
        lambda: live.host.query(
            "SELECT count(*) FROM jobs_job WHERE state = 'printing'"
        ) == [(1,)],
        PRINT_MS / 1000, "the job to print",
    )  # fmt: skip
    wait_for(
        lambda: live.host.query(
            "SELECT count(*) FROM jobs_fileanalysis WHERE state = 'done'"
        )[0][0] >= 1,
        60, "the analysis",
    )  # fmt: skip
    tab = open_tab(live.url, size)
    page = tab.page
    log_in(tab, OPERATOR)
    weight = first_load_bytes(tab, f"/printers/{SLUG}/")
    assert weight < 300_000, f"the printer page's first load is {weight} bytes"

    preview = page.locator("[data-test=preview]")
    expect(preview).to_be_visible(timeout=PRINT_MS)
    expect(preview).to_have_attribute("data-drawn", re.compile(r"^[1-9]\d*$"))
    label = preview.locator("[data-test=preview-label]")
    expect(label).to_have_text(re.compile(r"^Layer \d+ of 50 · Z \d+\.\d\d mm$"))
    # It follows the print: the shown layer is the live one, and it moves on.
    live_layer = int(preview.get_attribute("data-live-layer") or 0)
    assert live_layer >= 1
    expect(preview).to_have_attribute("data-layer", str(live_layer))
    expect(preview).not_to_have_attribute(
        "data-live-layer", str(live_layer), timeout=PRINT_MS
    )
    assert int(preview.get_attribute("data-live-layer") or 0) > live_layer
    # The canvas holds a picture, not a blank: some pixels are coloured.
    coloured = page.evaluate(
        """canvas => {
            const data = canvas.getContext("2d").getImageData(0, 0, canvas.width, canvas.height).data;
            let n = 0;
            for (let i = 0; i < data.length; i += 4) if (data[i + 3] > 0 && data[i] !== data[i + 2]) n += 1;
            return n;
        }""",
        preview.locator("[data-test=preview-canvas]").element_handle(),
    )
    assert coloured > 500, coloured
    tab.screenshot("preview", top="preview")

    # The slider picks a layer (and stops following); travel and colour redraw.
    slider = preview.locator("[data-test=preview-layer]")
    slider.fill("2")
    expect(label).to_have_text(re.compile(r"^Layer 3 of 50 · Z 0\.60 mm$"))
    expect(preview.locator("[data-test=preview-follow]")).not_to_be_checked()
    expect(preview).to_have_attribute("data-layer", "3")  # drawn, not only labelled
    drawn = preview.get_attribute("data-drawn")
    preview.locator("[data-test=preview-travel]").check()
    preview.locator("[data-test=preview-colour]").select_option("speed")
    expect(preview.locator("[data-test=preview-legend]")).to_contain_text("mm/s")
    assert preview.get_attribute("data-drawn") == drawn  # the same layer's lines

    # The job page of the running job shows the same file.
    job_id = live.host.query("SELECT id FROM jobs_job WHERE state = 'printing'")[0][0]
    tab.go(f"/jobs/{job_id}/")
    job_preview = page.locator("[data-test=preview]")
    expect(job_preview).to_be_visible(timeout=PRINT_MS)
    expect(job_preview.locator("[data-test=preview-label]")).to_have_text(
        re.compile(r"^Layer \d+ of 50")
    )
    expect(job_preview.locator("[data-test=preview-legend]")).to_contain_text(
        "Perimeter"
    )
    assert tab.unexpected_errors() == []
