"""An operator answers the printer's M600 prompt in real Chromium.

The job's M600 parks the simulated Marlin, which shows "Nozzle Parked" / "Continue"
(host prompt); the dashboard card and the printer page show it; a tap on Continue
sends M876 S0 and the job completes.
"""

from __future__ import annotations

import re
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

SLUG = "mk-m600"
GCODE = "G1 X10 F3000\nG1 X20\nM600\nG1 X30\nG1 X40\n"


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveHost]:
    folder = tmp_path_factory.mktemp("browser-prompt")
    yield from start_live_host(folder, {SLUG: "--time-scale 0"}, {SLUG: GCODE})


def test_an_operator_answers_the_filament_change_prompt(
    live: LiveHost, open_tab: Callable[..., Tab]
) -> None:
    tab = open_tab(live.url, "phone")
    page = tab.page
    log_in(tab, OPERATOR)

    card = page.locator(f"[data-test=printer-card][data-printer='{SLUG}']")
    card_prompt = card.locator("[data-test=prompt]")
    expect(card_prompt).to_be_visible(timeout=PRINT_MS)
    expect(card_prompt.locator("[data-test=prompt-message]")).to_have_text(
        "Nozzle Parked"
    )

    tab.go(f"/printers/{SLUG}/")
    prompt = page.locator("[data-test=prompt]")
    expect(prompt).to_be_visible()
    expect(prompt.locator("[data-test=prompt-message]")).to_have_text("Nozzle Parked")
    expect(prompt.locator("[data-test=prompt-hint]")).to_be_hidden()  # parser on
    expect(page.locator("[data-test=state-message]")).to_have_text(
        re.compile("waiting for the user: Nozzle Parked — Continue")
    )
    choice = prompt.locator("[data-test=prompt-choice]")
    expect(choice).to_have_text(["Continue"])
    box = choice.bounding_box()
    assert box is not None and box["height"] >= 44 and box["width"] >= 44, box
    assert "M876" not in live.record(SLUG)

    choice.click()
    expect(prompt).to_be_hidden()
    expect(page.locator("[data-test=error]")).to_be_hidden()
    wait_for(
        lambda: live.host.query("SELECT state FROM jobs_job")[0][0] == "completed",
        PRINT_MS / 1000, "the job to complete after the answer",
    )  # fmt: skip
    # Marlin acknowledges a move when it is queued and runs it after: the last
    # move reaches the record a moment after the job completes.
    wait_for(lambda: "G1 X40" in live.record(SLUG), 10, "the last move to run")
    record = live.record(SLUG)
    assert record.index("M600") < record.index("M876 S0")
    assert record.index("M600") < record.index("G1 X40")
