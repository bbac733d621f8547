"""A printhost installation in a folder, and runhost serving it, for end-to-end tests.

Real processes only: `manage.py` subprocesses for setup, `runhost` for daphne, the
simulators and the workers. Tests talk to it over real HTTP / websocket / TCP.
"""

from __future__ import annotations

import importlib
import json
import os
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from types import ModuleType

import pytest

from tests.conftest import ROOT, wait_for


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def services_required() -> bool:
    return os.environ.get("PRINTHOST_REQUIRE_SERVICES") == "1"


def import_or_skip(name: str) -> ModuleType:
    """*name*, or skip with a reason locally; in CI a missing module is an error."""
    try:
        return importlib.import_module(name)
    except ImportError as error:
        if services_required():
            raise
        pytest.skip(
            f"{name} is not installed ({error}); pip install -r requirements-dev.txt"
        )


def postgres_url() -> str:
    """A fresh database on the local PostgreSQL, or skip (fail in CI) if there is none."""
    psycopg = import_or_skip("psycopg")
    name = f"printhost_test_{uuid.uuid4().hex[:8]}"
    try:
        with psycopg.connect(
            "postgresql://postgres@127.0.0.1:5432/postgres", autocommit=True,
            connect_timeout=3,
        ) as connection:  # fmt: skip
            connection.execute(f"CREATE DATABASE {name}")
    except psycopg.OperationalError as error:
        if services_required():
            raise
        pytest.skip(f"PostgreSQL is not reachable on 127.0.0.1:5432 ({error})")
    return f"postgresql://postgres@127.0.0.1:5432/{name}"


def redis_url(db: int = 0) -> str:
    """The local Redis, or skip (fail in CI) if there is none."""
    redis = import_or_skip("redis")
    url = f"redis://127.0.0.1:6379/{db}"
    try:
        redis.Redis.from_url(url, socket_connect_timeout=3).ping()
    except redis.RedisError as error:
        if services_required():
            raise
        pytest.skip(f"Redis is not reachable on 127.0.0.1:6379 ({error})")
    return url


_TEMPLATE: list[Path] = []


def _migrated_sqlite() -> Path:
    """A SQLite database migrated by `manage.py migrate`, made once per session."""
    if not _TEMPLATE:
        folder = Path(tempfile.mkdtemp(prefix="printhost-migrated-"))
        env = {**os.environ, "PRINTHOST_DATA_DIR": str(folder)}
        env.pop("DATABASE_URL", None)
        subprocess.run(
            [sys.executable, "manage.py", "migrate", "--noinput"], cwd=ROOT, env=env,
            capture_output=True, text=True, check=True, timeout=120,
        )  # fmt: skip
        _TEMPLATE.append(folder / "printhost.sqlite3")
    return _TEMPLATE[0]


class Host:
    """A printhost installation in a folder: its own database, jobs and simulators."""

    def __init__(self, folder: Path, database_url: str = "", redis: str = "") -> None:
        self.folder = folder
        self.env = {**os.environ, "PRINTHOST_DATA_DIR": str(folder)}
        for name in ("DATABASE_URL", "REDIS_URL"):
            self.env.pop(name, None)
        if database_url:
            self.env["DATABASE_URL"] = database_url
        if redis:
            self.env["REDIS_URL"] = redis
        self.database_url = database_url
        self.port = 0

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def manage(
        self, *args: str, check: bool = True
    ) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "manage.py", *args], cwd=ROOT, env=self.env,
            capture_output=True, text=True, check=check, timeout=120,
        )  # fmt: skip

    def migrate(self) -> None:
        """The database, migrated. A SQLite host copies a database migrated once per
        test session (`migrate` costs two seconds a host); PostgreSQL migrates.
        The test of `make run`'s own steps runs `manage("migrate")` itself."""
        database = self.folder / "printhost.sqlite3"
        if self.database_url or database.exists():
            self.manage("migrate", "--noinput")
            return
        shutil.copyfile(_migrated_sqlite(), database)

    def shell(self, code: str) -> str:
        """What *code* prints, and nothing else: at `-v 0` Django's shell leaves out
        its first line, which counts the objects it imported."""
        return self.manage("shell", "-v", "0", "-c", code).stdout.strip()

    def query(self, sql: str) -> list[tuple]:
        if self.database_url:
            import psycopg

            with psycopg.connect(self.database_url) as connection:
                return connection.execute(sql).fetchall()
        with sqlite3.connect(
            self.folder / "printhost.sqlite3", timeout=20
        ) as connection:
            return connection.execute(sql).fetchall()

    def add_simulated_printer(
        self, slug: str, firmware: str = "marlin", *, baud: int = 250000,
        sim_args: str = "--time-scale 0", **fields: object,
    ) -> Path:  # fmt: skip
        """A printer driven by a simulator runhost starts; returns its record file."""
        link, record = self.folder / f"{slug}.tty", self.folder / f"{slug}.record"
        sim = f"{firmware} --link {link} --baud {baud} {sim_args} --record {record}"
        extra = {"temperature_interval": 0, **fields}
        self.shell(
            "from printers.models import Printer; Printer.objects.create("
            f"name={slug.upper()!r}, slug={slug!r}, firmware={firmware!r}, "
            f"port={str(link)!r}, baud={baud}, simulator={sim!r}, "
            f"**{json.dumps(extra)})"
        )
        return record

    def add_user(
        self, username: str, role: str = "", *, printer: str = "",
        superuser: bool = False, key_printer: str = "",
    ) -> str:  # fmt: skip
        """A user with *role* (viewer/operator/admin) on *printer* (or every printer).

        Returns a fresh API key of theirs (bound to *key_printer* if given); the
        password is the user name.
        """
        return self.add_users([(username, role, printer)], superuser, key_printer)[0]

    def add_users(
        self,
        users: list[tuple[str, str, str]],
        superuser: bool = False,
        key_printer: str = "",
    ) -> list[str]:
        """Several users (name, role, printer) in one `manage.py shell` (each shell
        costs a Django start-up); their fresh API keys in order."""
        code = f"""
from django.contrib.auth import get_user_model
from printers.models import Printer
from printhost.access import issue_key
from printhost.models import PrinterRole, Role
User = get_user_model()
bound = {key_printer!r}
for username, role, printer in {users!r}:
    user = User.objects.create_user(username, password=username,
        is_superuser={superuser}, is_staff={superuser})
    if role:
        PrinterRole.objects.create(user=user, role=Role[role.upper()],
            printer=Printer.objects.get(slug=printer) if printer else None)
    key, raw = issue_key(user, "test", printer=Printer.objects.get(slug=bound) if bound else None)
    print("key:", raw)
"""
        lines = self.shell(code).splitlines()
        return [line[5:] for line in lines if line.startswith("key: ")]

    @contextmanager
    def running(
        self, *extra: str, web: bool = True, celery: bool = False
    ) -> Iterator[subprocess.Popen]:
        """runhost (daphne, simulators, workers) until the block ends; HTTP is up.

        Its Celery worker and beat run only when *celery* is set: most tests do not
        need file analysis, and two more processes per host slow a 2-core machine.
        """
        self.port = free_port()
        args = ["--port", str(self.port)] if web else ["--no-web"]
        if not celery:
            args.append("--no-celery")
        log = (self.folder / "runhost.log").open("wb")
        process = subprocess.Popen(
            [sys.executable, "manage.py", "runhost", *args, *extra], cwd=ROOT,
            env=self.env, stdout=log, stderr=subprocess.STDOUT,
        )  # fmt: skip
        try:
            if web:
                wait_for(
                    lambda: _accepts(self.port) or process.poll() is not None,
                    60, "daphne to listen",
                )  # fmt: skip
                assert process.poll() is None, self.log_tail()
            yield process
        finally:
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(timeout=60)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
            log.close()

    @contextmanager
    def celery(self, *args: str, log_name: str) -> Iterator[subprocess.Popen]:
        """`python -m celery --app printhost <args>` as runhost starts it, in its own
        process group, logging to *log_name* in the folder, until the block ends."""
        with (self.folder / log_name).open("wb") as log:
            process = subprocess.Popen(
                [sys.executable, "-m", "celery", "--app", "printhost", *args,
                 "--loglevel", "INFO"],
                cwd=ROOT, env=self.env, stdout=log, stderr=subprocess.STDOUT,
                start_new_session=True,
            )  # fmt: skip
            try:
                yield process
            finally:
                if process.poll() is None:
                    os.killpg(process.pid, signal.SIGTERM)
                    try:
                        process.wait(timeout=30)
                    except subprocess.TimeoutExpired:
                        os.killpg(process.pid, signal.SIGKILL)
                        process.wait()

    def run_printer(self, slug: str) -> subprocess.Popen[bytes]:
        """`manage.py run_printer <slug>`: one printer's worker, output discarded."""
        return subprocess.Popen(
            [sys.executable, "manage.py", "run_printer", slug], cwd=ROOT,
            env=self.env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip

    def lease_expired(self) -> bool:
        """The (only) printer's worker lease has run out, or was never taken."""
        (expires,) = self.query("SELECT lease_expires_at FROM printers_printer")[0]
        now = datetime.now(UTC).strftime("%Y-%m-%d %H:%M:%S.%f")
        return expires is None or str(expires)[:26] < now

    def log_tail(self, lines: int = 40) -> str:
        path = self.folder / "runhost.log"
        text = path.read_text(errors="replace") if path.exists() else ""
        return "\n".join(text.splitlines()[-lines:])


def _accepts(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.5):
            return True
    except OSError:
        return False
