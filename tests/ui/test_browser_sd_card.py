"""The printer's SD card in real Chromium: listed, printed from, deleted from.

A simulated Marlin whose card is a folder holding CUBE.GCO and BOAT.GCO; the printer
page lists them (M20 at connect), Print queues a print from the card that runs to
its end on the printer, and Delete removes a file from the card and the list.
"""

from __future__ import annotations

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

SLUG = "mk-sd"
CUBE = "G28\nG1 X10 Y10 F3000\nG1 X20\nG1 Y20\n"


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveHost]:
    folder = tmp_path_factory.mktemp("browser-sd")
    card = folder / "card"
    card.mkdir()
    (card / "CUBE.GCO").write_text(CUBE)
    (card / "BOAT.GCO").write_text("G28\n")
    yield from start_live_host(folder, {SLUG: f"--time-scale 0 --sd-dir {card}"})


def test_an_operator_prints_from_the_card_and_deletes_a_file(
    live: LiveHost, open_tab: Callable[..., Tab]
) -> None:
    tab = open_tab(live.url, "phone")
    page = tab.page
    log_in(tab, OPERATOR, f"/printers/{SLUG}/")

    panel = page.locator("[data-test=sd-card]")
    files = panel.locator("[data-test=sd-file]")
    expect(files).to_have_count(2, timeout=PRINT_MS)  # listed live at connect
    expect(panel.locator("[data-test=sd-status]")).to_contain_text("2 files")

    panel.locator(
        "[data-test=sd-file][data-name='CUBE.GCO'] [data-test=sd-print]"
    ).click()
    expect(page.locator("[data-test=error]")).to_be_hidden()
    row = page.locator("[data-test=queue-job]").filter(has_text="CUBE.GCO")
    expect(row.locator("[data-test=queue-job-kind]")).to_have_text("from SD card")
    wait_for(
        lambda: live.host.query("SELECT state FROM jobs_job WHERE kind = 'sd_print'")
        == [("completed",)],
        PRINT_MS / 1000, "the print from the card to complete",
    )  # fmt: skip
    wait_for(lambda: "G1 Y20" in live.record(SLUG), 10, "the card's lines to run")

    page.once("dialog", lambda dialog: dialog.accept())
    panel.locator(
        "[data-test=sd-file][data-name='BOAT.GCO'] [data-test=sd-delete]"
    ).click()
    expect(files).to_have_count(1, timeout=PRINT_MS)
    assert not (live.folder / "card" / "BOAT.GCO").exists()
    assert tab.unexpected_errors() == []
