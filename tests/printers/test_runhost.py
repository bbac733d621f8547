"""runhost end to end, in real processes: a SIGKILLed worker, the CLI's errors."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from printers.sample_gcode import commands_of, segments
from tests.conftest import HOST_COMMANDS, ROOT, wait_for
from tests.hosts import Host, postgres_url

pytestmark = pytest.mark.slow


@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.services)])
def host(request: pytest.FixtureRequest, tmp_path: Path) -> Host:
    url = postgres_url() if request.param == "postgres" else ""
    host = Host(tmp_path, url)
    host.migrate()
    return host


def test_sigkilled_worker_is_restarted_and_its_job_left_interrupted(host: Host):
    link, record = host.folder / "p0.tty", host.folder / "p0.record"
    sim = f"marlin --link {link} --baud 250000 --time-scale 0 --record {record}"
    host.shell(
        "from printers.models import Printer; Printer.objects.create(name='P0', "
        f"slug='p0', port={str(link)!r}, baud=250000, simulator={sim!r}, "
        "temperature_interval=0)"
    )
    text = segments(20000)
    (host.folder / "job.gcode").write_text(text)
    host.manage("add_job", "p0", str(host.folder / "job.gcode"))
    # A short lease: the new worker takes the printer 4 s after the kill, not 10.
    env = {**host.env, "PRINTHOST_LEASE_SECONDS": "4"}
    runhost = subprocess.Popen(
        [sys.executable, "manage.py", "runhost", "--no-web", "--no-celery"], cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        acked = lambda: host.query("SELECT lines_acked FROM jobs_job")[0][0]
        wait_for(lambda: acked() > 1000, 60, "the job to be well under way")
        owner = host.query("SELECT lease_owner FROM printers_printer")[0][0]
        os.kill(int(owner.split(":")[1]), signal.SIGKILL)

        state = lambda: host.query("SELECT state, lines_acked, message FROM jobs_job")[
            0
        ]
        wait_for(lambda: state()[0] == "interrupted", 60, "the job to be interrupted")
        new_owner = lambda: host.query("SELECT lease_owner FROM printers_printer")[0][0]
        wait_for(lambda: new_owner() not in ("", owner), 60, "a new worker")
        wait_for(
            lambda: host.query("SELECT state FROM printers_printer")[0][0] == "waitstart",
            30, "the printer to wait for a clear bed",
        )  # fmt: skip
    finally:
        runhost.send_signal(signal.SIGTERM)
        runhost.wait(timeout=60)

    job_state, lines_acked, message = state()
    ran = [
        c for c in record.read_text().splitlines() if not c.startswith(HOST_COMMANDS)
    ]
    assert ran == commands_of(text)[: len(ran)], "a line was repeated or skipped"
    assert 1000 < lines_acked <= len(ran) < 20003
    assert f"at line {lines_acked} of 20003" in message
    assert runhost.returncode == 0
    assert host.query("SELECT lease_owner FROM printers_printer")[0][0] == ""


def test_run_printer_with_an_unknown_slug_exits_with_a_clear_error(tmp_path: Path):
    host = Host(tmp_path)
    host.migrate()
    done = host.manage("run_printer", "nope", check=False)
    assert done.returncode == 1
    assert "unknown printer 'nope'" in done.stderr


@pytest.mark.parametrize(
    ("content", "error"),
    [
        (b"", "holds no G-code command"),
        (b"; only a comment\n\n", "holds no G-code command"),
        (b"G28\n\x00\x01\x02\x89PNG", "binary file"),
        (b"G28\nG1 X" + b"1" * 100 + b"\n", "the firmware takes at most"),
    ],
    ids=["empty", "comments-only", "binary", "line-too-long"],
)
def test_add_job_refuses_bad_files_with_a_clear_error(tmp_path: Path, content, error):
    host = Host(tmp_path)
    host.migrate()
    host.shell(
        "from printers.models import Printer; "
        "Printer.objects.create(name='P', slug='p', port='/dev/null')"
    )
    bad = tmp_path / "bad.gcode"
    bad.write_bytes(content)
    done = host.manage("add_job", "p", str(bad), check=False)
    assert done.returncode == 1
    assert error in done.stderr
    assert host.query("SELECT count(*) FROM jobs_job") == [(0,)]
