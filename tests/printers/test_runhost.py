"""runhost end to end, in real processes: a SIGKILLed worker, the CLI's errors."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from printers.sample_gcode import commands_of, segments
from tests.conftest import HOST_COMMANDS, ROOT, wait_for

pytestmark = pytest.mark.slow


class Host:
    """A printhost installation in a folder: its own database, jobs and simulators."""

    def __init__(self, folder: Path, database_url: str = "") -> None:
        self.folder = folder
        self.env = {**os.environ, "PRINTHOST_DATA_DIR": str(folder)}
        self.env.pop("DATABASE_URL", None)
        if database_url:
            self.env["DATABASE_URL"] = database_url
        self.database_url = database_url

    def manage(
        self, *args: str, check: bool = True
    ) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "manage.py", *args], cwd=ROOT, env=self.env,
            capture_output=True, text=True, check=check, timeout=120,
        )  # fmt: skip

    def shell(self, code: str) -> str:
        return self.manage("shell", "-c", code).stdout.strip()

    def query(self, sql: str) -> list[tuple]:
        if self.database_url:
            import psycopg

            with psycopg.connect(self.database_url) as connection:
                return connection.execute(sql).fetchall()
        with sqlite3.connect(
            self.folder / "printhost.sqlite3", timeout=20
        ) as connection:
            return connection.execute(sql).fetchall()


def postgres_url() -> str:
    """A fresh database on the local PostgreSQL, or skip (fail in CI) if there is none."""
    psycopg = pytest.importorskip("psycopg")
    name = f"printhost_test_{uuid.uuid4().hex[:8]}"
    try:
        with psycopg.connect(
            "postgresql://postgres@127.0.0.1:5432/postgres", autocommit=True,
            connect_timeout=3,
        ) as connection:  # fmt: skip
            connection.execute(f"CREATE DATABASE {name}")
    except psycopg.OperationalError as error:
        if os.environ.get("PRINTHOST_REQUIRE_SERVICES") == "1":
            raise
        pytest.skip(f"PostgreSQL is not reachable on 127.0.0.1:5432 ({error})")
    return f"postgresql://postgres@127.0.0.1:5432/{name}"


@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.services)])
def host(request: pytest.FixtureRequest, tmp_path: Path) -> Host:
    url = postgres_url() if request.param == "postgres" else ""
    host = Host(tmp_path, url)
    host.manage("migrate", "--noinput")
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
    runhost = subprocess.Popen(
        [sys.executable, "manage.py", "runhost", "--no-web"], cwd=ROOT, env=host.env,
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
    host.manage("migrate", "--noinput")
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
    host.manage("migrate", "--noinput")
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
