"""The history page in real Chromium at phone and tablet size: a job printed on the
simulator is listed with its totals, the filters narrow the list, nothing scrolls
sideways, and the screenshots the README shows are taken."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from printers.sample_gcode import segments
from tests.conftest import wait_for
from tests.ui.conftest import (
    OPERATOR,
    VIEWER,
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

SLUG, OTHER = "mk3", "voron"

#: Earlier runs of other outcomes, written as the worker's end of a run writes them
#: (the live printer prints one job; these fill the page as a farm's week would).
EARLIER_RUNS = f"""
from datetime import timedelta
from django.utils import timezone
from jobs.history import HistoryEntry
from printers.models import Printer
done = HistoryEntry.objects.get()
now = timezone.now()
shared = dict(sha256=done.sha256, kind="print", user=done.user,
    user_name=done.user_name, line_count=2000, layers=40, metadata={{}})
runs = [
    ("{SLUG}", "benchy.gcode", "aborted", 26, 1.5, 912.4, 12, "", None, 0),
    ("{SLUG}", "bracket.gcode", "failed", 30, 0.4, 210.0, 3,
     "printer halted: thermal runaway on T0", None, 0),
    ("{OTHER}", "enclosure-lid.gcode", "interrupted", 50, 3.2, 5120.0, 21,
     "interrupted: the worker stopped at line 1012 of 2000", None, 0),
    ("{OTHER}", "enclosure-lid.gcode", "completed", 46, 2.9, 4880.0, 40, "", 9001, 1012),
]
for number, (slug, name, outcome, hours_ago, hours, filament, layer, message,
             resumed, line) in enumerate(runs, start=9000):
    printer = Printer.objects.get(slug=slug)
    started = now - timedelta(hours=hours_ago)
    HistoryEntry.objects.create(job_number=number, printer=printer,
        printer_name=printer.name, printer_slug=slug, name=name, origin="http:olga",
        started_at=started, finished_at=started + timedelta(hours=hours),
        outcome=outcome, message=message, resumed_from=resumed, start_line=line,
        lines_acked=line + 900, print_seconds=hours * 3600, filament_used=filament,
        layer=layer, **shared)
"""


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveHost]:
    folder = tmp_path_factory.mktemp("browser-history")
    yield from start_live_host(
        folder, {SLUG: "--time-scale 0", OTHER: ""}, jobs={SLUG: segments(40)}
    )


@pytest.fixture(scope="module")
def printed(live: LiveHost) -> LiveHost:
    """The queued job printed by the worker (its entry written), and earlier runs."""
    wait_for(
        lambda: live.host.query("SELECT count(*) FROM jobs_historyentry")[0][0] > 0,
        60,
        "the printed job's history entry",
    )
    live.host.shell(EARLIER_RUNS)
    return live


def no_sideways_scroll(tab: Tab) -> None:
    width = tab.page.evaluate(
        "() => [document.documentElement.scrollWidth, innerWidth]"
    )
    assert width[0] <= width[1], f"the page scrolls sideways: {width[0]} > {width[1]}"


@pytest.mark.parametrize("size", list(VIEWPORTS))
def test_history_page_lists_runs_with_totals_and_filters(
    size: str, printed: LiveHost, open_tab: Callable[..., Tab]
) -> None:
    tab = open_tab(printed.url, size)
    log_in(tab, OPERATOR)
    tab.page.locator("[data-test=nav-history]").click()
    page = tab.page
    page.wait_for_url("**/history/")

    runs = page.locator("[data-test=run]")
    expect(runs).to_have_count(5)
    expect(page.locator("[data-test=total-jobs]")).to_have_text("5")
    expect(page.locator("[data-test=total-success]")).to_have_text("40 %")
    first_print = page.locator(
        f"[data-test=run][data-outcome=completed] >> text={SLUG}"
    )
    expect(first_print.first).to_be_visible()
    resumed = page.locator("[data-test=run-resumed]")
    expect(resumed).to_have_text("Resumed from line 1012 of #9001")
    csv = page.locator("[data-test=history-csv]")
    expect(csv).to_have_attribute("href", "/printer/history?format=csv")
    no_sideways_scroll(tab)
    if size == "phone":  # cards one above the other
        boxes = [runs.nth(i).bounding_box() for i in range(2)]
        assert boxes[0]["x"] == boxes[1]["x"] and boxes[1]["y"] > boxes[0]["y"]
    tab.screenshot("history")

    page.locator("[data-test=filters-box] summary").click()
    page.select_option("[data-test=filter-outcome]", "failed")
    page.locator("[data-test=filter-apply]").click()
    page.wait_for_url("**/history/?*outcome=failed*")
    expect(runs).to_have_count(1)
    expect(page.locator("[data-test=run-message]")).to_have_text(
        "printer halted: thermal runaway on T0"
    )
    expect(csv).to_have_attribute("href", "/printer/history?outcome=failed&format=csv")


def test_a_viewer_sees_only_the_printers_they_may_view(
    printed: LiveHost, open_tab: Callable[..., Tab]
) -> None:
    tab = open_tab(printed.url, "tablet")
    log_in(tab, VIEWER)
    tab.go("/history/")

    runs = tab.page.locator("[data-test=run]")
    expect(runs).to_have_count(3)
    assert OTHER not in tab.page.locator("[data-test=runs]").inner_text().lower()
