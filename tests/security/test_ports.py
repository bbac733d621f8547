"""A printer's port names a serial device (or a listed TCP host), never another URL.

`printers.ports.check_port` is the one check: the model (admin forms, the config
API) and the worker's transport use it. Port, baud and simulator are a superuser's.
"""

from __future__ import annotations

import io
import os
import subprocess
import sys

import pytest
from django.contrib.admin.sites import site
from django.core.exceptions import ValidationError
from django.test import RequestFactory

from printers.admin import PrinterAdmin
from printers.models import Printer, ResponseLine
from printers.ports import PortRefused, check_port, simulator_paths_outside
from printers.worker.loop import PrinterWorker
from printhost.access import issue_key
from printhost.models import PrinterRole, Role
from tests.conftest import ROOT

BAD_PORTS = [
    "spy:///dev/ttyUSB0?file=/tmp/spied.txt",
    "SPY:///dev/ttyUSB0",
    "loop://",
    "hwgrep://.*",
    "alt:///dev/ttyUSB0?class=PosixPollSerial",
    "cp2110://0001:0004:00",
    "socket://127.0.0.1:6379",
    "socket://127.0.0.1:5432",
    "rfc2217://evil.example:2217",
    "socket://user@127.0.0.1:7000",
    "socket://printer.lan:23?logging=debug",
    "socket://printer.lan",
    "ttyUSB0",
    "../dev/ttyUSB0",
    "/etc/passwd",
    "/dev/../etc/passwd",
    "/dev/sda",
    "/dev/mem",
    "/dev/ttyUSB0/../../etc/passwd",
    "/tmp/printer.tty",
    " /dev/ttyUSB0",
    "",
]


@pytest.mark.parametrize("port", BAD_PORTS)
def test_check_port_refuses_urls_and_paths_that_are_not_serial_devices(tmp_path, port):
    with pytest.raises(PortRefused):
        check_port(port, data_dir=tmp_path, hosts=["printer.lan:23"])


@pytest.mark.parametrize(
    "port",
    [
        "/dev/ttyUSB0",
        "/dev/ttyACM1",
        "/dev/tty.usbserial-1420",
        "/dev/serial/by-id/usb-Prusa_Research_Original_Prusa_MK3-if00",
        "/dev/serial/by-path/pci-0000:00:14.0-usb-0:1:1.0",
        "socket://printer.lan:23",
        "rfc2217://PRINTER.lan:23",
        "socket://[::1]:7000",
    ],
)
def test_check_port_allows_devices_and_listed_hosts(tmp_path, port):
    check_port(port, data_dir=tmp_path, hosts=["printer.lan:23", "[::1]:7000"])


def test_links_in_the_data_dir_must_lead_to_a_serial_device(tmp_path, sim_factory):
    sim = sim_factory("marlin", "--time-scale", "0")
    check_port(str(sim.link), data_dir=tmp_path)
    check_port(str(tmp_path / "not-started-yet.tty"), data_dir=tmp_path)
    secret = tmp_path / "printhost.sqlite3"
    secret.write_text("data")
    (tmp_path / "evil.tty").symlink_to("/etc/passwd")
    for bad in (secret, tmp_path / "evil.tty", tmp_path):
        with pytest.raises(PortRefused):
            check_port(str(bad), data_dir=tmp_path)


def test_simulator_files_must_stay_in_the_data_dir(tmp_path):
    inside = f"marlin --link {tmp_path}/sim/a --record {tmp_path}/a.record"
    assert simulator_paths_outside(inside, data_dir=tmp_path) == []
    outside = simulator_paths_outside(
        f"marlin --link {tmp_path}/a --record /tmp/x.record --control=../c "
        "--sd-dir /etc",
        data_dir=tmp_path,
    )
    assert outside == [
        "--record /tmp/x.record",
        "--control ../c (give an absolute path)",
        "--sd-dir /etc",
    ]


def test_the_simulator_refuses_a_record_file_outside_the_data_dir(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    done = subprocess.run(
        [sys.executable, "-m", "printers.simulator", "marlin", "--link",
         str(data / "p.tty"), "--record", str(tmp_path / "outside.record")],
        cwd=ROOT, env={**os.environ, "PRINTHOST_DATA_DIR": str(data)},
        capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    assert done.returncode == 2
    assert "--record" in done.stderr and "inside the data directory" in done.stderr
    assert not (tmp_path / "outside.record").exists()


def test_the_simulator_refuses_a_card_folder_outside_the_data_dir(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    done = subprocess.run(
        [sys.executable, "-m", "printers.simulator", "marlin", "--link",
         str(data / "p.tty"), "--sd-dir", str(tmp_path)],
        cwd=ROOT, env={**os.environ, "PRINTHOST_DATA_DIR": str(data)},
        capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    assert done.returncode == 2
    assert "--sd-dir" in done.stderr and "inside the data directory" in done.stderr


# -- the model, the admin, the config API ------------------------------------------

pytestmark_db = pytest.mark.django_db


@pytestmark_db
@pytest.mark.parametrize("port", ["spy:///dev/ttyUSB0?file=/tmp/x", "loop://"])
def test_model_validation_refuses_a_bad_port_and_simulator(make_printer, port):
    printer = make_printer(port="/dev/ttyUSB0")
    printer.port = port
    printer.simulator = "marlin --link /tmp/l --record /tmp/r"
    with pytest.raises(ValidationError) as refused:
        printer.full_clean()
    assert set(refused.value.message_dict) == {"port", "simulator"}


def _admin_request(user):
    request = RequestFactory().get("/admin/")
    request.user = user
    return request


@pytestmark_db
def test_admin_form_refuses_each_bad_port_with_a_form_error(
    make_printer, django_user_model
):
    printer = make_printer(port="/dev/ttyUSB0")
    root = django_user_model.objects.create_superuser("root", "", "pw")
    model_admin = PrinterAdmin(Printer, site)
    form_class = model_admin.get_form(_admin_request(root), printer)
    base = {
        f: getattr(printer, f)
        for f in form_class.base_fields
        if getattr(printer, f, None) is not None
    }
    for port in ("spy:///dev/ttyUSB0?file=/tmp/x", "socket://127.0.0.1:6379"):
        form = form_class(data={**base, "port": port}, instance=printer)
        assert not form.is_valid()
        assert port in " ".join(form.errors["port"])
    printer.refresh_from_db()
    assert printer.port == "/dev/ttyUSB0"


@pytestmark_db
def test_admin_shows_port_baud_and_simulator_read_only_to_non_superusers(
    make_printer, django_user_model
):
    printer = make_printer()
    staff = django_user_model.objects.create_user("staff", password="pw", is_staff=True)
    root = django_user_model.objects.create_superuser("root", "", "pw")
    model_admin = PrinterAdmin(Printer, site)
    staff_fields = model_admin.get_readonly_fields(_admin_request(staff), printer)
    root_fields = model_admin.get_readonly_fields(_admin_request(root), printer)
    assert {"port", "baud", "simulator"} <= set(staff_fields)
    assert not {"port", "baud", "simulator"} & set(root_fields)
    form = model_admin.get_form(_admin_request(staff), printer)
    assert not {"port", "baud", "simulator"} & set(form.base_fields)


@pytestmark_db
def test_config_api_refuses_bad_ports_and_needs_a_superuser_for_port_and_baud(
    make_printer, django_user_model, client
):
    printer = make_printer(port="/dev/ttyUSB0")
    root = django_user_model.objects.create_superuser("root", "", "pw")
    boss = django_user_model.objects.create_user("boss", password="pw")
    PrinterRole.objects.create(user=boss, printer=printer, role=Role.ADMIN)
    _, root_key = issue_key(root, "t")
    _, boss_key = issue_key(boss, "t")

    def patch(key, body):
        return client.patch(
            f"/printer/config/{printer.slug}", body,
            content_type="application/json", HTTP_X_API_KEY=key,
        )  # fmt: skip

    for port in BAD_PORTS[:12]:
        response = patch(root_key, {"port": port})
        assert response.status_code == 400, (port, response.content)
        assert "port" in response.json()["error"]
    for change in ({"port": "/dev/ttyACM0"}, {"baud": 9600}):
        response = patch(boss_key, change)
        assert response.status_code == 403, response.content
        assert "needs a superuser" in response.json()["error"]
    assert (
        patch(boss_key, {"auto_start": True, "port": "/dev/ttyUSB0"}).status_code == 200
    )
    assert patch(root_key, {"port": "/dev/ttyACM0", "baud": 9600}).status_code == 200
    printer.refresh_from_db()
    assert (printer.port, printer.baud, printer.auto_start) == (
        "/dev/ttyACM0",
        9600,
        True,
    )


# -- the worker --------------------------------------------------------------------


@pytestmark_db
def test_worker_never_opens_a_bad_port_already_in_the_database(
    make_printer, sim_factory, tmp_path
):
    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "0")
    spied = tmp_path / "spied.txt"
    printer = make_printer(port=f"spy://{sim.link}?file={spied}", baud=250000)
    worker = PrinterWorker(printer)
    worker.start()
    try:
        for _ in range(3):
            worker.tick()
        worker.status.save_if_due(worker.clock(), force=True)
        printer.refresh_from_db()
    finally:
        worker.stop()

    assert worker.transport is None
    assert not spied.exists()
    assert printer.state == "error", "retrying a refused port cannot help"
    assert "spy:// ports are not allowed" in printer.state_message
    texts = " ".join(
        ResponseLine.objects.filter(printer=printer).values_list("text", flat=True)
    )
    assert "cannot open port" in texts and "spy:// ports are not allowed" in texts


@pytestmark_db
def test_the_demo_printers_pass_the_port_and_simulator_checks(settings, tmp_path):
    from django.core.management import call_command

    from printers.models import Printer

    settings.DATA_DIR = tmp_path
    settings.JOB_STORAGE_DIR = tmp_path / "jobs"
    call_command("setup_demo", stdout=io.StringIO())
    printers = list(Printer.objects.all())
    assert {p.slug for p in printers} == {"marlin-sim", "grbl-sim"}
    for printer in printers:
        printer.full_clean()  # the port and the simulator's paths are allowed
        check_port(printer.port, data_dir=tmp_path)
    marlin = Printer.objects.get(slug="marlin-sim")
    assert "--sd-dir" in marlin.simulator
    assert (tmp_path / "sim" / "marlin-sim-sd" / "SQUARE.GCO").is_file()


@pytestmark_db
def test_printer_page_shows_port_and_baud_read_only_to_non_superusers(
    make_printer, django_user_model, client
):
    printer = make_printer(port="/dev/ttyUSB0")
    boss = django_user_model.objects.create_user("boss", password="pw")
    PrinterRole.objects.create(user=boss, printer=printer, role=Role.ADMIN)
    root = django_user_model.objects.create_superuser("root", "", "pw")

    client.force_login(boss)
    page = client.get(f"/printers/{printer.slug}/").content.decode()
    assert 'data-test="connection-form"' not in page
    assert '<dd data-test="port">/dev/ttyUSB0</dd>' in page
    assert 'data-test="port-superuser"' in page
    client.force_login(root)
    page = client.get(f"/printers/{printer.slug}/").content.decode()
    assert 'data-test="connection-form"' in page
