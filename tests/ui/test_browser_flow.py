"""A person at a phone or a tablet runs a whole print in real Chromium.

Log in, upload a file (the progress bar is seen filling), watch the job print live
(state, progress, terminal), pause and resume, confirm the bed is clear, press the
emergency stop. The screenshots in docs/screenshots/ come from these runs.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

import pytest

from printers.sample_gcode import segments
from tests.conftest import wait_for
from tests.ui.conftest import (
    OPERATOR,
    PRINT_MS,
    STEP_MS,
    VIEWPORTS,
    LiveHost,
    Tab,
    log_in,
    playwright_api,
    start_live_host,
)

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from pathlib import Path

    from playwright.sync_api import Locator, Page

pytestmark = pytest.mark.slow

expect = playwright_api().expect

#: One printer per viewport: the emergency stop at the end leaves the firmware halted.
SLUGS = {size: f"mk-{size}" for size in VIEWPORTS}

#: A travel move out to the circle, then 900 short segments: about 9 s of printing
#: on the simulator at real speed, long enough to watch, pause and resume.
GCODE = "G0 X150 Y100 F30000\nG1 F3000\n" + segments(900)

#: Upload speed while the file goes up (bytes/s), so the bar is seen moving.
UPLOAD_BYTES_PER_SECOND = 8 * 1024

#: Samples the upload bar every 20 ms: [visible, value, max].
SAMPLE_UPLOAD_BAR = """() => {
  window.__uploadBar = [];
  window.__uploadTimer = setInterval(() => {
    const bar = document.querySelector('[data-test=upload-progress]');
    if (!bar) return;
    const box = bar.getBoundingClientRect();
    const shown = box.width > 0 && box.height > 0
      && getComputedStyle(bar).visibility !== 'hidden';
    window.__uploadBar.push([shown, Number(bar.value), Number(bar.max)]);
  }, 20);
}"""


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveHost]:
    folder = tmp_path_factory.mktemp("browser-flow")
    # --time-scale 1: moves take their real time, so a job lasts a few seconds.
    printers = dict.fromkeys(SLUGS.values(), "--time-scale 1")
    yield from start_live_host(folder, printers)


def state_of(page: Page) -> Locator:
    return page.locator("[data-test=state]")


def progress_value(page: Page) -> float:
    return float(
        page.locator("[data-test=job] [data-test=progress]").evaluate("e => e.value")
    )


def no_error_shown(page: Page) -> None:
    expect(page.locator("[data-test=error]")).to_be_hidden()


@pytest.mark.parametrize("size", list(VIEWPORTS))
def test_an_operator_prints_a_job_from_upload_to_emergency_stop(
    size: str, live: LiveHost, open_tab: Callable[..., Tab], tmp_path: Path
) -> None:
    slug = SLUGS[size]
    tab = open_tab(live.url, size)
    page = tab.page

    # The login page, then log in through its form.
    tab.go("/accounts/login/")
    tab.screenshot("login")
    log_in(tab, OPERATOR)

    # Dashboard: a card for the printer, with its emergency stop.
    card = page.locator(f"[data-test=printer-card][data-printer='{slug}']")
    expect(card).to_be_visible()
    expect(card.locator("[data-test=estop]")).to_be_visible()
    expect(card.locator("[data-test=state]")).to_have_text(re.compile("idle", re.I))
    tab.screenshot("dashboard")

    # The printer page, through the card's link.
    with page.expect_navigation(wait_until="load"):
        card.locator(f"a[href='/printers/{slug}/']").first.click()
    expect(page.locator("[data-test=estop]")).to_be_visible()
    expect(state_of(page)).to_have_text(re.compile("idle", re.I))
    terminal = page.locator("[data-test=terminal]")
    expect(terminal).to_be_visible()

    # Upload, throttled so the progress bar is really seen filling.
    source = tmp_path / f"ring-{size}.gcode"
    source.write_text(GCODE)
    page.set_input_files("[data-test=upload-file]", str(source))
    cdp = page.context.new_cdp_session(page)
    cdp.send("Network.enable")
    cdp.send(
        "Network.emulateNetworkConditions",
        {
            "offline": False,
            "latency": 0,
            "downloadThroughput": -1,
            "uploadThroughput": UPLOAD_BYTES_PER_SECOND,
        },
    )
    page.evaluate(SAMPLE_UPLOAD_BAR)
    page.locator("[data-test=upload]").click()
    expect(page.locator("[data-test=upload-progress]")).to_be_visible()
    page.wait_for_function(
        "() => window.__uploadBar.some(([shown, value, max]) =>"
        " shown && max > 0 && value >= max)",
        timeout=STEP_MS,
    )
    samples = page.evaluate("() => { clearInterval(window.__uploadTimer);"
                            " return window.__uploadBar; }")  # fmt: skip
    cdp.send(
        "Network.emulateNetworkConditions",
        {"offline": False, "latency": 0, "downloadThroughput": -1,
         "uploadThroughput": -1},
    )  # fmt: skip
    partway = [s for s in samples if s[0] and 0 < s[1] < s[2]]
    assert partway, f"the upload bar was never seen part-filled: {samples[:20]}"
    no_error_shown(page)

    # The job is in the queue and starts (the printer is idle).
    row = page.locator("[data-test=queue-job]", has_text=source.name)
    expect(row).to_be_visible()
    start = row.locator("[data-test=job-start]")
    if start.is_visible():
        start.click()
    expect(state_of(page)).to_have_text(re.compile("printing", re.I), timeout=STEP_MS)
    expect(page.locator("[data-test=job] [data-test=job-name]")).to_contain_text(
        source.name
    )

    # Live: the progress rises and the terminal gets new lines, no reload.
    lines = page.locator("[data-test=terminal] [data-test=line]")
    seen_lines, seen_progress = lines.count(), progress_value(page)
    page.wait_for_function(
        "n => document.querySelectorAll("
        "'[data-test=terminal] [data-test=line]').length > n",
        arg=seen_lines,
        timeout=STEP_MS,
    )
    page.wait_for_function(
        "p => document.querySelector('[data-test=job] [data-test=progress]').value > p",
        arg=seen_progress,
        timeout=STEP_MS,
    )
    tab.screenshot("printer")

    # Pause and resume.
    page.locator("[data-test=pause]").click()
    expect(state_of(page)).to_have_text(re.compile("paused", re.I), timeout=STEP_MS)
    paused_at = progress_value(page)
    page.locator("[data-test=resume]").click()
    expect(state_of(page)).to_have_text(re.compile("printing", re.I), timeout=STEP_MS)
    no_error_shown(page)

    # It finishes; the printer waits for the bed to be cleared; confirm it.
    bed_clear = page.locator("[data-test=bed-clear]")
    expect(bed_clear).to_be_visible(timeout=PRINT_MS)
    assert progress_value(page) >= paused_at
    expect(state_of(page)).not_to_have_text(re.compile("printing|paused", re.I))
    bed_clear.click()
    expect(state_of(page)).to_have_text(re.compile("idle", re.I), timeout=STEP_MS)
    expect(bed_clear).to_be_hidden()
    no_error_shown(page)

    # The job's page: its facts and its runs.
    [job_id] = live.job_ids(slug)
    with page.expect_navigation(wait_until="load"):
        row.locator(f"a[href='/jobs/{job_id}/']").first.click()
    expect(page.locator("[data-test=job-facts]")).to_contain_text(source.name)
    expect(page.locator("[data-test=runs]")).to_contain_text(
        re.compile("completed", re.I)
    )
    tab.screenshot("job")

    # The account page, through the user menu.
    page.locator("[data-test=user-menu]").click()
    with page.expect_navigation(wait_until="load"):
        page.locator("[data-test=account-link]").click()
    assert page.url.endswith("/account/"), page.url
    expect(page.locator("[data-test=keys]")).to_be_visible()
    tab.screenshot("account")

    # Emergency stop: M112 reaches the firmware.
    tab.go(f"/printers/{slug}/")
    assert "M112" not in live.record(slug)
    page.locator("[data-test=estop]").click()
    wait_for(lambda: "M112" in live.record(slug), 15, "M112 at the firmware")
    no_error_shown(page)
