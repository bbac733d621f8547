"""The farm page in real Chromium at phone and tablet size, against runhost with
simulated printers and its dispatcher: jobs uploaded to the farm go to the printers
that match, the others say why they wait, and setting a printer's loaded material
on the page sends a waiting job there. Writes docs/screenshots/farm-*.png."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from tests.conftest import wait_for
from tests.farm.conftest import box_gcode
from tests.ui.conftest import (
    OPERATOR,
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

pytestmark = pytest.mark.slow

expect = playwright_api().expect

#: Three simulated printers on this server, one offline on a worker host.
PRINTERS = {
    "mk3-a": "--time-scale 0",
    "mk3-b": "--time-scale 0",
    "voron": "--time-scale 0",
    "rack-mk4": "",
}

SETUP = """
from datetime import timedelta
from django.utils import timezone
from printers.hosts import WorkerHost
from printers.models import Printer
mk3 = {"min": [0, -4, 0], "max": [250, 210, 210]}
voron = {"min": [0, 0, 0], "max": [350, 350, 340]}
rack = WorkerHost.objects.create(name="rack-1", version="0.1.0", seen_at=timezone.now(),
    hostname="rack-1", load={"loadavg": [0.31, 0.28, 0.2], "cpus": 4})
for slug, material, colour, volume, nozzle in (
    ("mk3-a", "PLA", "black", mk3, 0.4), ("mk3-b", "PETG", "orange", mk3, 0.4),
    ("voron", "PLA", "white", voron, 0.6), ("rack-mk4", "PLA", "grey", mk3, 0.4),
):
    Printer.objects.filter(slug=slug).update(material=material, colour=colour,
        build_volume=volume, nozzle_diameter=nozzle, loaded_by="olga",
        loaded_at=timezone.now())
Printer.objects.filter(slug="rack-mk4").update(worker_host=rack, name="MK4 on rack 1")
"""
#: rack-1 has no runhost: its heartbeat is written by hand, before each page that
#: shows it online (the module's pages may come a minute or more after SETUP).
BEAT = """
from django.utils import timezone
from printers.hosts import WorkerHost
WorkerHost.objects.filter(name="rack-1").update(seen_at=timezone.now())
"""

#: Farm uploads, analysed here as the Celery worker would.
UPLOADS = """
import io
from jobs.analysis_task import run
from jobs.farm.requirements import parse_requirements
from jobs.farm.storing import store_farm_upload
for name, text, asks in {uploads!r}:
    farm_job = store_farm_upload(io.BytesIO(text.encode()), name=name,
        requirements=parse_requirements(asks), origin="test")
    run(farm_job.analysis_id, worker="test")
"""

UPLOADED = [
    ("bracket-pla.gcode", box_gcode(60, 40, 10), {"material": "PLA"}),
    ("clip-petg.gcode", box_gcode(30, 20, 8), {"material": "PETG"}),
    ("hinge-asa.gcode", box_gcode(50, 30, 12), {"material": "ASA"}),
    ("tower.gcode", box_gcode(100, 100, 300), {}),
    ("lid-tpu.gcode", box_gcode(80, 80, 6), {"material": "TPU", "nozzle": "0.6"}),
]


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveHost]:
    folder = tmp_path_factory.mktemp("browser-farm")
    yield from start_live_host(folder, PRINTERS)


@pytest.fixture(scope="module")
def routed(live: LiveHost) -> LiveHost:
    """The uploads made, and the dispatcher (started by runhost once the farm is
    used) done with the ones a printer can take."""
    host = live.host
    wait_for(
        lambda: host.query(
            "SELECT count(*) FROM printers_printer WHERE state = 'idle'"
        )[0][0] == 3,
        60, "the three simulated printers to be idle",
    )  # fmt: skip
    host.shell(SETUP)
    host.shell(UPLOADS.format(uploads=UPLOADED))
    wait_for(
        lambda: host.query(
            "SELECT count(*) FROM jobs_farmjob WHERE state = 'assigned'"
        )[0][0] == 3,
        60, "the dispatcher to give the PLA, PETG and tall jobs",
    )  # fmt: skip
    return live


def where(live: LiveHost) -> dict[str, str | None]:
    rows = live.host.query(
        "SELECT f.name, p.slug FROM jobs_farmjob f LEFT JOIN printers_printer p "
        "ON p.id = f.printer_id"
    )
    return dict(rows)


def no_sideways_scroll(tab: Tab) -> None:
    width = tab.page.evaluate(
        "() => [document.documentElement.scrollWidth, innerWidth]"
    )
    assert width[0] <= width[1], f"the page scrolls sideways: {width[0]} > {width[1]}"


def test_jobs_go_to_matching_printers_and_the_rest_say_why(routed: LiveHost) -> None:
    went = where(routed)
    assert went["tower.gcode"] == "voron"  # only its volume is tall enough
    assert went["clip-petg.gcode"] == "mk3-b"
    assert went["bracket-pla.gcode"] == "mk3-a"  # the smaller volume first
    assert went["hinge-asa.gcode"] is None and went["lid-tpu.gcode"] is None


@pytest.mark.parametrize("size", list(VIEWPORTS))
def test_the_farm_page_shows_queue_reasons_hosts_and_materials(
    size: str, routed: LiveHost, open_tab: Callable[..., Tab]
) -> None:
    routed.host.shell(BEAT)
    tab = open_tab(routed.url, size)
    log_in(tab, OPERATOR)
    tab.page.locator("[data-test=nav-farm]").click()
    page = tab.page
    page.wait_for_url("**/farm/")

    asa = page.locator("[data-test=farm-job]", has_text="hinge-asa.gcode")
    expect(asa.locator("[data-test=farm-reason]")).to_have_text(
        "no printer has ASA loaded"
    )
    tpu = page.locator("[data-test=farm-job]", has_text="lid-tpu.gcode")
    expect(tpu.locator("[data-test=farm-reason]")).to_have_text(
        "no printer has TPU loaded"
    )
    tower = page.locator("[data-test=farm-job]", has_text="tower.gcode")
    expect(tower.locator("[data-test=farm-went]")).to_contain_text("Went to voron")
    rack = page.locator("[data-test=farm-host][data-host=rack-1]")
    expect(rack.locator("[data-test=host-heartbeat]")).to_contain_text("online")
    expect(rack.locator("[data-test=host-facts]")).to_have_text(
        "printhost 0.1.0 · load 0.31 · 4 CPUs"
    )
    expect(rack.locator("[data-test=farm-printer]")).to_have_count(1)
    expect(
        page.locator("[data-test=farm-material][data-material='black PLA']")
    ).to_be_visible()
    no_sideways_scroll(tab)
    if size == "phone":  # one column: the queue above the printers
        queue = page.locator("[data-test=farm-queue]").bounding_box()
        hosts = page.locator("[data-test=farm-hosts]").bounding_box()
        assert hosts["y"] > queue["y"] + queue["height"] - 1
    tab.screenshot("farm")


def test_setting_a_printers_material_on_the_page_routes_the_waiting_job(
    routed: LiveHost, open_tab: Callable[..., Tab]
) -> None:
    host = routed.host
    # The bed of the printer that printed is confirmed clear, as an operator would.
    wait_for(
        lambda: host.query(
            "SELECT count(*) FROM printers_printer WHERE state = 'waitstart'"
        )[0][0] == 3,
        60, "the three farm jobs to print",
    )  # fmt: skip
    tab = open_tab(routed.url, "tablet")
    log_in(tab, OPERATOR, "/printers/mk3-b/")
    page = tab.page
    page.locator("[data-test=bed-clear]").click()
    form = page.locator("[data-test=loaded-form]")
    form.locator("input[name=material]").fill("ASA")
    form.locator("input[name=colour]").fill("")
    form.locator("[data-test=loaded-save]").click()
    expect(page.locator("[data-test=loaded-material]")).to_have_text("ASA")

    tab.go("/farm/")
    asa = page.locator("[data-test=farm-job]", has_text="hinge-asa.gcode")
    expect(asa.locator("[data-test=farm-went]")).to_contain_text(
        "Went to mk3-b", timeout=3 * STEP_MS
    )
    assert where(routed)["hinge-asa.gcode"] == "mk3-b"
    (loaded_by,) = host.query(
        "SELECT loaded_by FROM printers_printer WHERE slug = 'mk3-b'"
    )[0]
    assert loaded_by == OPERATOR
