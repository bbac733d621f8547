"""The farm page's first render (queue, printers by host and by material), who may see
it, and what the dashboard and the printer page show of the farm."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest
from django.contrib.auth import get_user_model
from django.db import connection
from django.test import Client
from django.utils import timezone

from jobs.farm.dispatch import Dispatcher
from printers.hosts import WorkerHost
from printhost.models import PrinterRole, Role
from tests.farm.conftest import box_gcode

if TYPE_CHECKING:
    from collections.abc import Callable

    from jobs.farm.models import FarmJob
    from printers.models import Printer

pytestmark = pytest.mark.django_db


def browser(role: str, printer: Printer | None = None) -> Client:
    user = get_user_model().objects.create_user(f"{role}-{printer}")
    PrinterRole.objects.create(user=user, role=Role[role.upper()], printer=printer)
    client = Client()
    client.force_login(user)
    return client


def test_the_farm_page_shows_the_queue_and_printers_by_host_and_material(
    farm_printer: Callable[..., Printer], to_farm: Callable[..., FarmJob]
) -> None:
    rack = WorkerHost.objects.create(
        name="rack-1", seen_at=timezone.now(), version="0.1.0",
        load={"loadavg": [0.42, 0.3, 0.2], "cpus": 4, "clock_offset_s": 3600.2},
    )  # fmt: skip
    farm_printer("mk3-a", worker_host=rack, material="PLA", colour="black")
    farm_printer("mk3-b", worker_host=rack, material="PLA", colour="black")
    farm_printer("voron", material="PETG", nozzle_diameter=0.6)
    to_farm(box_gcode(100, 50, 30), name="given.gcode")
    Dispatcher().run_pass()
    to_farm(box_gcode(90, 50, 30), name="asa.gcode", material="ASA")
    Dispatcher().run_pass()
    to_farm(box_gcode(80, 50, 30), name="next.gcode")

    page = browser("viewer").get("/farm/")

    assert page.status_code == 200
    html = page.content.decode()
    assert "no printer has ASA loaded" in html
    assert 'data-test="farm-would-go">Would go to <a href="/printers/mk3-b/">' in html
    assert 'Went to <a href="/printers/mk3-a/">mk3-a</a> as <a href="/jobs/' in html
    assert 'data-host="rack-1"' in html and "online · " in html
    assert "printhost 0.1.0 · load 0.42 · 4 CPUs" in html
    assert "its clock is 3600 s behind the database&#x27;s: set up NTP" in html
    assert 'data-host="this server"' in html
    assert 'data-material="black PLA"' in html and 'data-material="PETG"' in html
    assert "2 waiting · 2 of 3 farm printers free" in html
    assert 'data-test="farm-cancel"' not in html  # a viewer cannot change the queue
    assert 'data-test="loaded-form"' not in html


@pytest.mark.parametrize(
    "load",
    [
        {"loadavg": ["high"], "cpus": "four"},
        {"loadavg": 0.5, "cpus": -1},
        {"loadavg": [[1]], "cpus": True},
        {"loadavg": [10**400], "cpus": 10**400},  # past any float
        ["not", "a", "dict"],
    ],
)
def test_a_heartbeat_with_junk_for_its_load_leaves_the_pages_up(
    farm_printer: Callable[..., Printer], load: object
) -> None:
    """The worker host writes its row: a bad value shows no load, not a 500."""
    rack = WorkerHost.objects.create(name="rack-1", seen_at=timezone.now(), load=load)
    farm_printer("mk3-a", worker_host=rack)
    client = browser("viewer")
    for path in ("/farm/", "/"):
        page = client.get(path)
        assert page.status_code == 200, path
        html = page.content.decode()
        assert 'data-host="rack-1"' in html
        assert "· load" not in html and "CPUs" not in html


def test_rows_a_worker_wrote_with_integers_too_long_to_read_leave_the_pages_up(
    farm_printer: Callable[..., Printer],
) -> None:
    """Past Python's 4,300 digits int() refuses a number: read as a float, shown as
    no value, rather than a 500 on every page that reads the host or printer."""
    rack = WorkerHost.objects.create(name="rack-1", seen_at=timezone.now())
    farm_printer("mk3-a", worker_host=rack)
    huge = "9" * 5000
    with connection.cursor() as cursor:
        cursor.execute(
            "UPDATE printers_workerhost SET load = %s, printers = %s",
            [f'{{"loadavg": [{huge}], "cpus": {huge}}}', f'{{"mk3-a": {huge}}}'],
        )
        cursor.execute(
            "UPDATE printers_printer SET temperatures = %s, link_stats = %s",
            [f'{{"T0": [{huge}, 200]}}', f'{{"link_use": {huge}}}'],
        )
    client = browser("viewer")
    for path in ("/farm/", "/", "/printer/farm", "/printer/list"):
        assert client.get(path).status_code == 200, path


def test_operators_get_the_queues_buttons_and_the_loaded_forms_of_their_printers(
    farm_printer: Callable[..., Printer], to_farm: Callable[..., FarmJob]
) -> None:
    farm_printer("mk3")
    to_farm(box_gcode(100, 50, 30), analyse=False)
    html = browser("operator").get("/farm/").content.decode()
    assert 'data-test="farm-cancel"' in html and 'data-test="loaded-form"' in html


def test_the_farm_page_needs_a_role_on_every_printer(
    farm_printer: Callable[..., Printer],
) -> None:
    mk3 = farm_printer("mk3")
    page = browser("operator", mk3).get("/farm/")
    assert page.status_code == 403
    assert "viewer role needed on every printer" in page.content.decode()
    assert Client().get("/farm/").status_code == 302  # to the login page


def test_dashboard_and_printer_page_show_the_host_and_what_is_loaded(
    farm_printer: Callable[..., Printer],
) -> None:
    rack = WorkerHost.objects.create(name="rack-2")
    farm_printer("mk3", worker_host=rack, material="PETG", colour="orange",
                 nozzle_diameter=0.6)  # fmt: skip
    client = browser("operator")

    dashboard = client.get("/").content.decode()
    assert "orange PETG, 0.6 mm" in dashboard
    assert '<span data-test="card-host">rack-2</span>' in dashboard
    page = client.get("/printers/mk3/").content.decode()
    assert '<dd data-test="worker-host">rack-2</dd>' in page
    assert '<dd data-test="loaded-material">orange PETG</dd>' in page
    assert 'data-test="loaded-form"' in page


def test_the_admin_lists_farm_jobs_and_keeps_a_given_one_read_only(
    farm_printer: Callable[..., Printer],
    to_farm: Callable[..., FarmJob],
    admin_client: Client,
) -> None:
    farm_printer("mk3")
    given = to_farm(box_gcode(100, 50, 30), name="given.gcode")
    Dispatcher().run_pass()
    waiting = to_farm(box_gcode(90, 50, 30), name="waiting.gcode", material="ASA")

    listing = admin_client.get("/admin/jobs/farmjob/").content.decode()
    assert "given.gcode" in listing and "waiting.gcode" in listing
    editable = admin_client.get(f"/admin/jobs/farmjob/{waiting.pk}/change/")
    assert 'name="material"' in editable.content.decode()
    frozen = admin_client.get(f"/admin/jobs/farmjob/{given.pk}/change/")
    assert 'name="material"' not in frozen.content.decode()
