"""A control plane and a worker host as separate installations on one PostgreSQL:
the host runs its printer, fetches the job's file over HTTP and prints it exactly;
the control plane drives no printer."""

from __future__ import annotations

from pathlib import Path

import pytest

from printers.sample_gcode import commands_of, segments
from tests.conftest import HOST_COMMANDS, wait_for
from tests.hosts import Host, postgres_url

pytestmark = [pytest.mark.slow, pytest.mark.services]


def test_a_worker_host_prints_a_job_queued_on_the_control_plane(tmp_path: Path):
    database = postgres_url()
    control = Host(tmp_path / "control", database)
    shelf = Host(tmp_path / "shelf", database)
    for host in (control, shelf):
        host.folder.mkdir()
    control.migrate()
    added = control.manage("worker_host", "add", "shelf-1").stdout
    key = added.split("key (shown once): ")[1].split()[0]
    record = shelf.add_simulated_printer("p1", sim_args="--time-scale 0")
    shelf.shell(
        "from printers.models import Printer; from printers.hosts import WorkerHost; "
        "Printer.objects.filter(slug='p1').update("
        "worker_host=WorkerHost.objects.get(name='shelf-1'))"
    )
    text = segments(3000)
    source = tmp_path / "part.gcode"
    source.write_text(text)
    control.manage("add_job", "p1", str(source))

    with control.running("--no-workers"):
        shelf.env["PRINTHOST_CONTROL_URL"] = control.url
        shelf.env["PRINTHOST_HOST_KEY"] = key
        with shelf.running("--worker-host", "shelf-1", web=False) as runhost:
            state = lambda: control.query("SELECT state, message FROM jobs_job")[0]
            wait_for(lambda: state()[0] == "completed", 90, "the job to complete")
            host = control.query(
                "SELECT instance, printers, version FROM printers_workerhost"
            )[0]
            assert str(runhost.pid) in host[0] and host[2]
            assert '"p1"' in str(host[1]).replace("'", '"')
        assert control.query("SELECT instance FROM printers_workerhost")[0][0] == ""

    ran = [
        c for c in record.read_text().splitlines() if not c.startswith(HOST_COMMANDS)
    ]
    assert ran == commands_of(text)
    sha = control.query("SELECT sha256 FROM jobs_job")[0][0]
    assert (shelf.folder / "cache" / "jobs" / sha).read_text() == text
    assert not (shelf.folder / "jobs").exists()  # no job storage on the host
    assert "worker:p1" not in control.log_tail(200)
    assert "fetches job" in control.log_tail(200)
