"""One worker per port on a computer (a kernel lock), and a lease that never hands a
printer to a worker on another host."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from printers.hosts import WorkerHost
from printers.worker.lease import Lease, LeaseLost
from printers.worker.portlock import PortBusy, PortLock
from tests.conftest import ROOT
from tests.hosts import Host


def test_a_second_lock_on_a_port_is_refused_until_the_first_is_released(tmp_path):
    first = PortLock("/dev/ttyACM7", tmp_path)
    first.acquire()
    with pytest.raises(PortBusy, match=r"another worker on this computer \(pid \d+\)"):
        PortLock("/dev/ttyACM7", tmp_path).acquire()
    PortLock("/dev/ttyACM8", tmp_path).acquire()  # another port: its own lock
    first.release()
    PortLock("/dev/ttyACM7", tmp_path).acquire()


def test_two_names_of_one_device_share_the_lock(tmp_path):
    device = tmp_path / "ttyUSB0"
    device.touch()
    by_id = tmp_path / "usb-Prusa_MK4-if00"
    by_id.symlink_to(device)
    PortLock(str(device), tmp_path / "locks").acquire()
    with pytest.raises(PortBusy):
        PortLock(str(by_id), tmp_path / "locks").acquire()


def test_a_killed_holder_leaves_the_port_free(tmp_path):
    code = (
        "import sys; from pathlib import Path;"
        "import django, os; os.environ.setdefault('DJANGO_SETTINGS_MODULE',"
        "'printhost.settings'); django.setup();"
        "from printers.worker.portlock import PortLock;"
        f"PortLock('/dev/ttyACM7', Path({str(tmp_path)!r})).acquire();"
        "print('held', flush=True); sys.stdin.read()"  # holds it until killed
    )
    holder = subprocess.Popen(
        [sys.executable, "-c", code], cwd=ROOT, stdin=subprocess.PIPE,
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(PortBusy, match=f"pid {holder.pid}"):
            PortLock("/dev/ttyACM7", tmp_path).acquire()
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    PortLock("/dev/ttyACM7", tmp_path).acquire()


def test_run_printer_for_a_port_another_worker_drives_exits_before_it_writes(
    tmp_path: Path,
):
    host = Host(tmp_path)
    host.migrate()
    host.shell(
        "from printers.models import Printer; Printer.objects.create(name='P', "
        "slug='p1', port='/dev/ttyACM7', state='printing', state_message='busy')"
    )
    PortLock("/dev/ttyACM7", tmp_path / "locks").acquire()
    result = host.manage("run_printer", "p1", check=False)
    assert result.returncode == 1
    assert "printer p1: /dev/ttyACM7 is driven by another worker" in result.stderr
    row = host.query("SELECT state, state_message, lease_owner FROM printers_printer")
    assert row == [("printing", "busy", "")]


@pytest.mark.django_db
def test_a_lease_is_taken_only_by_a_worker_on_the_printers_own_host(make_printer):
    shelf1 = WorkerHost.objects.create(name="shelf-1")
    WorkerHost.objects.create(name="shelf-2")
    printer = make_printer(worker_host=shelf1)
    local = make_printer()
    with pytest.raises(LeaseLost, match="driven from worker host shelf-1, not from "
                       "worker host shelf-2"):  # fmt: skip
        Lease(printer.pk, "b:1:x", 10, host="shelf-2").take(0.0)
    with pytest.raises(LeaseLost, match="not from no worker host"):
        Lease(printer.pk, "c:1:x", 10, host="").take(0.0)
    with pytest.raises(LeaseLost, match="driven from the control plane's runhost"):
        Lease(local.pk, "d:1:x", 10, host="shelf-1").take(0.0)
    Lease(printer.pk, "a:1:x", 10, host="shelf-1").take(0.0)
    Lease(local.pk, "e:1:x", 10, host="").take(0.0)
