"""One worker per printer, in real processes: the loser of a lease writes nothing."""

from __future__ import annotations

import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from printers.sample_gcode import commands_of, segments
from tests.conftest import HOST_COMMANDS, ROOT, wait_for
from tests.hosts import Host

pytestmark = pytest.mark.slow


def _host_with_job(tmp_path: Path, port: str, lines: int) -> tuple[Host, str]:
    host = Host(tmp_path)
    if "://" in port:  # a network port is opened only to a listed host
        host.env["PRINTHOST_PORT_HOSTS"] = port.split("://", 1)[1]
    host.migrate()
    host.shell(
        "from printers.models import Printer; Printer.objects.create(name='P0', "
        f"slug='p0', port={port!r}, baud=250000, temperature_interval=0)"
    )
    text = segments(lines)
    (tmp_path / "job.gcode").write_text(text)
    host.manage("add_job", "p0", str(tmp_path / "job.gcode"))
    return host, text


def _worker(host: Host) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "manage.py", "run_printer", "p0"], cwd=ROOT, env=host.env,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip


def _stop(*workers: subprocess.Popen[str]) -> None:
    for worker in workers:
        if worker.poll() is None:
            worker.send_signal(signal.SIGTERM)
    for worker in workers:
        try:
            worker.wait(timeout=60)
        except subprocess.TimeoutExpired:
            worker.kill()
            worker.wait()


def test_two_workers_on_one_socket_printer_exactly_one_drives_it(
    tmp_path: Path, sim_factory
):
    sim = sim_factory("marlin", "--time-scale", "0", "--tcp", "127.0.0.1:0")
    host, text = _host_with_job(tmp_path, f"socket://{sim.tcp}", 3000)
    workers = [_worker(host), _worker(host)]
    try:
        wait_for(
            lambda: any(w.poll() is not None for w in workers), 60,
            "one of the two workers to give up the printer",
        )  # fmt: skip
        loser = next(w for w in workers if w.poll() is not None)
        winner = next(w for w in workers if w is not loser)
        job = lambda: host.query("SELECT state, lines_acked FROM jobs_job")[0]
        wait_for(lambda: job()[0] == "completed", 120, "the winner to print the job")
        owner = host.query("SELECT lease_owner FROM printers_printer")[0][0]
    finally:
        _stop(*workers)

    _, errors = loser.communicate()
    assert loser.returncode == 1
    assert "driven by" in errors
    assert owner.split(":")[1] == str(winner.pid)
    assert f":{loser.pid}:" not in owner
    ran = [c for c in sim.executed() if not c.startswith(HOST_COMMANDS)]
    assert ran == commands_of(text), "every line exactly once: only one worker sent"
    assert job() == ("completed", len(commands_of(text)))
    assert host.query("SELECT state FROM printers_printer")[0][0] == "offline"


def _take_over(host: Host) -> dict[str, list[tuple]]:
    """Another owner takes the row; returns what the database held at that moment."""
    with sqlite3.connect(
        host.folder / "printhost.sqlite3", timeout=20, isolation_level=None
    ) as connection:
        connection.execute("BEGIN IMMEDIATE")
        connection.execute(
            "UPDATE printers_printer SET lease_owner = 'thief:0:abcdef', "
            "lease_expires_at = '2999-01-01 00:00:00'"
        )
        snapshot = _snapshot(connection)
        connection.execute("COMMIT")
    return snapshot


def _snapshot(connection: sqlite3.Connection) -> dict[str, list[tuple]]:
    queries = {
        "printer": "SELECT * FROM printers_printer",
        "job": "SELECT * FROM jobs_job",
        "log": "SELECT count(*), max(seq) FROM printers_responseline",
        "samples": "SELECT count(*) FROM printers_temperaturesample",
    }
    return {name: connection.execute(sql).fetchall() for name, sql in queries.items()}


def test_worker_whose_lease_was_taken_over_stops_and_writes_nothing_more(
    tmp_path: Path, sim_factory
):
    sim = sim_factory("marlin", "--time-scale", "0", "--baud", "250000")
    host, _ = _host_with_job(tmp_path, str(sim.link), 20000)
    worker = _worker(host)
    try:
        acked = lambda: host.query("SELECT lines_acked FROM jobs_job")[0][0]
        wait_for(lambda: acked() > 200, 60, "the job to be under way")
        before = _take_over(host)
        wait_for(lambda: worker.poll() is not None, 30, "the worker to let go")
    finally:
        _stop(worker)

    _, errors = worker.communicate()
    assert worker.returncode == 1
    assert "thief:0:abcdef" in errors
    with sqlite3.connect(host.folder / "printhost.sqlite3") as connection:
        after = _snapshot(connection)
    assert after == before, "the worker wrote after it lost its lease"
    executed = len(sim.executed())
    assert executed < 20000, "the worker stopped feeding the printer"
