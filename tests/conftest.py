"""Shared fixtures: firmware simulators on real ptys, printers, and bounded waits."""

from __future__ import annotations

import compileall
import contextlib
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from printers.simulator.process import SimulatorProcess, start_simulator

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

ROOT = Path(__file__).resolve().parent.parent


Sim = SimulatorProcess


def start_sim(directory: Path, firmware: str, *args: str, name: str = "") -> Sim:
    """Start `python -m printers.simulator` and wait (bounded) for its ready line."""
    return start_simulator(directory, firmware, *args, name=name)


@pytest.fixture
def sim_factory(tmp_path: Path) -> Iterator[Callable[..., Sim]]:
    """Start simulators in this test's folder; all are stopped afterwards."""
    started: list[Sim] = []

    def factory(firmware: str, *args: str, name: str = "") -> Sim:
        sim = start_sim(tmp_path, firmware, *args, name=name)
        started.append(sim)
        return sim

    yield factory
    for sim in started:
        sim.stop()


@contextlib.contextmanager
def rows_made(*models: type) -> Iterator[list[object]]:
    """Every row of *models* created inside the block, even one deleted again before
    it ends (a queued job lives long enough for its worker to start it)."""
    from django.db.models.signals import post_save

    made: list[object] = []

    def note(sender: type, instance: object, created: bool, **kwargs: object) -> None:
        if created:
            made.append(instance)

    for model in models:
        post_save.connect(note, sender=model, weak=False)
    try:
        yield made
    finally:
        for model in models:
            post_save.disconnect(note, sender=model)


def wait_for(
    predicate: Callable[[], object],
    timeout: float,
    what: str,
    step: Callable[[], None] | None = None,
) -> None:
    """Call *step* (or poll) until *predicate* holds; fail with *what* after *timeout*."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        if step is not None:
            step()
        else:
            time.sleep(0.02)


@pytest.fixture
def storage(settings: object, tmp_path: Path) -> Path:
    """Job files and the data directory inside this test's folder; a fast poll."""
    settings.JOB_STORAGE_DIR = tmp_path / "jobs"  # type: ignore[attr-defined]
    # The simulators' pty links are here: printers.ports lets a worker open them.
    settings.DATA_DIR = tmp_path  # type: ignore[attr-defined]
    settings.PRINTHOST_POLL_SECONDS = 0.02  # type: ignore[attr-defined]
    settings.PRINTHOST_JOURNAL_DIR = tmp_path / "journal"  # type: ignore[attr-defined]
    settings.ANALYSIS_DIR = tmp_path / "analysis"  # type: ignore[attr-defined]
    return tmp_path / "jobs"


@pytest.fixture
def make_printer(db: None, storage: Path) -> Callable[..., object]:
    """Create a printer row; keyword arguments override the defaults."""
    from printers.models import Printer

    def factory(**fields: object) -> Printer:
        values: dict[str, object] = {
            "name": "Test printer",
            "slug": f"p{Printer.objects.count() + 1}",
            "port": "/nonexistent",
            "temperature_interval": 0,
            "status_interval": 0,
            "ack_timeout": 5.0,
        }
        values.update(fields)
        return Printer.objects.create(**values)

    return factory


@pytest.fixture
def make_job(storage: Path, tmp_path: Path) -> Callable[..., object]:
    """Queue a job holding *text* on *printer* through the real enqueue path."""
    from jobs.services import enqueue_job

    def factory(printer: object, text: str, name: str = "job.gcode") -> object:
        source = tmp_path / name
        source.write_text(text)
        return enqueue_job(printer, source, name=name, origin="test")

    return factory


#: Commands the worker sends by itself (hello, temperatures, the quickstop after a
#: Marlin job that failed or was aborted, when asked for), not part of any job.
HOST_COMMANDS = ("M110", "M115", "M105", "M155", "M876", "M410", "$I")


def job_lines(sim: Sim) -> list[str]:
    """Job commands the firmware ran (a reset's torn line fragment is not a command)."""
    return [
        c
        for c in sim.executed()
        if c.startswith(("G", "M")) and not c.startswith(HOST_COMMANDS)
    ]


@pytest.fixture(autouse=True)
def fast_password_hashing(settings: object) -> None:
    """Tests create many users; a deliberately slow hash would dominate their time."""
    settings.PASSWORD_HASHERS = ["django.contrib.auth.hashers.MD5PasswordHasher"]  # type: ignore[attr-defined]


@pytest.fixture(autouse=True)
def database_clock_just_read(monkeypatch: pytest.MonkeyPatch) -> None:
    """A web request reads the database's clock when this process last did a
    minute ago or more (printhost/shared_clock.py): taken here as just read, so
    that the queries a test counts do not hang on when the last test ran. The
    tests of that reading (tests/workerhosts/test_web_clock.py) set it back."""
    from printers import dbclock

    monkeypatch.setattr(dbclock, "_learned_at", float("inf"))


def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile the project to bytecode once, before any test starts a process.

    The tests start hundreds of Python processes (runhost, workers, simulators,
    `manage.py` calls). Where PYTHONDONTWRITEBYTECODE is set, as on CI images,
    none of them writes its .pyc, so each compiled every module it imported
    again: about half a second of CPU per Django process on a small machine.
    """
    if os.environ.get("PYTEST_XDIST_WORKER"):
        return  # the controller did it before starting the workers
    for folder in ("printhost", "printers", "jobs", "tests", "bench"):
        compileall.compile_dir(ROOT / folder, quiet=1)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The slow tests first, each module's tests still together and in order.

    `make test` runs three workers that steal from each other; begun last (the
    browser tests and the worker hosts sort at the end), the longest tests left a
    tail of one or two busy workers for minutes.
    """
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


def _services_required() -> bool:
    return os.environ.get("PRINTHOST_REQUIRE_SERVICES") == "1"


def pytest_terminal_summary(
    terminalreporter: pytest.TerminalReporter, exitstatus: int, config: pytest.Config
) -> None:
    """In CI (PRINTHOST_REQUIRE_SERVICES=1) a skipped test is a failed run: list them."""
    if not _services_required():
        return
    skipped = terminalreporter.stats.get("skipped", [])
    if not skipped:
        return
    terminalreporter.section("skips are failures in CI", red=True)
    for report in skipped:
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else ""
        terminalreporter.line(f"SKIPPED {report.nodeid}: {reason}", red=True)
    terminalreporter.line(
        f"{len(skipped)} test(s) skipped with PRINTHOST_REQUIRE_SERVICES=1;"
        " CI has every service and module, so a skip hides a test that did not run",
        red=True,
    )


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Turn a CI run that skipped anything into a failing exit status."""
    if not _services_required():
        return
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    skipped = reporter.stats.get("skipped", []) if reporter is not None else []
    if skipped and exitstatus == pytest.ExitCode.OK:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED
