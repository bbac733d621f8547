"""The database goes away mid-print and comes back: the print goes on at full speed,
and nothing is lost from the response log or the progress; nobody else drives it.

A real worker (`runhost`) reaches a real PostgreSQL through a TCP proxy the test
cuts for longer than the lease; the control plane's reaper, which still reaches
the database, takes the printer for dead meanwhile; the worker, back, says the run
went on and finishes it. And a command whose row the worker could not mark taken
(the connection dropped at that very write) runs once, never again after."""

from __future__ import annotations

import re
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import urlparse

import pytest

from printers.sample_gcode import commands_of, segments
from tests.conftest import HOST_COMMANDS, wait_for
from tests.hosts import Host, postgres_url
from tests.netfault import TcpProxy

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

pytestmark = [pytest.mark.slow, pytest.mark.services]

LEASE = 3.0


def test_a_print_goes_on_while_the_database_is_away_and_nothing_is_lost(
    tmp_path: Path,
):
    direct = postgres_url()
    host = Host(tmp_path, direct)
    host.migrate()
    record = host.add_simulated_printer("p1", sim_args="--time-scale 0")
    # Long enough that the print is still running when the database is back, on a
    # loaded machine too (the reaper's checks each start a Django process).
    text = segments(12000)
    (tmp_path / "part.gcode").write_text(text)
    host.manage("add_job", "p1", str(tmp_path / "part.gcode"))

    proxy = TcpProxy(("127.0.0.1", 5432))
    worker_side = Host(tmp_path, proxy.url("postgresql", urlparse(direct).path,
                                           user="postgres"))  # fmt: skip
    worker_side.env["PRINTHOST_LEASE_SECONDS"] = str(LEASE)
    ran = lambda: len(record.read_text().splitlines()) if record.exists() else 0
    job = lambda: host.query("SELECT state, lines_acked, line_count FROM jobs_job")[0]
    owner = lambda: host.query("SELECT lease_owner FROM printers_printer")[0][0]
    try:
        with worker_side.running(web=False):
            wait_for(lambda: job()[1] > 1500, 60, "the print to be under way")
            driver = owner()
            proxy.cut()
            at_cut = ran()
            # The firmware goes on running lines while the worker cannot write.
            wait_for(lambda: ran() > at_cut + 1000, 60, "the print to go on")
            # The control plane, which still reaches the database, takes the
            # printer for dead once the lease has run out.
            wait_for(
                lambda: host.shell(
                    "from printers.reaper import reap_silent_workers; "
                    "print(reap_silent_workers())"
                ) != "[]",
                30, "the reaper to take the silent worker for dead",
            )  # fmt: skip
            assert job()[0] == "interrupted"
            assert ran() < len(commands_of(text)), "the print ended during the cut"
            proxy.restore()
            wait_for(lambda: job()[0] == "completed", 90, "the job to complete")
            log = worker_side.log_tail(400)
    finally:
        proxy.close()

    commands = commands_of(text)
    printed = [c for c in record.read_text().splitlines()
               if not c.startswith(HOST_COMMANDS)]  # fmt: skip
    assert printed == commands, "a line was lost or repeated"
    state, acked, count = job()
    assert (state, acked) == ("completed", count)
    assert owner() == "" and driver  # one driver, released at the stop
    assert "LeaseLost" not in log and "lease lost" not in log
    assert "the database does not answer" in log and "answers again" in log

    # The response log: every id once, in order, and every job line sent in it.
    seqs = [row[0] for row in host.query(
        "SELECT seq FROM printers_responseline ORDER BY seq")]  # fmt: skip
    assert seqs == list(range(1, len(seqs) + 1))
    sent = [row[0] for row in host.query(
        "SELECT text FROM printers_responseline WHERE kind = 1 ORDER BY seq")]  # fmt: skip
    framed = re.compile(r"^N\d+ (.*)\*\d+$")
    sent = [framed.sub(r"\1", line) for line in sent]
    job_lines = [line for line in sent if not line.startswith(HOST_COMMANDS)]
    assert job_lines == commands
    notes = " ".join(row[0] for row in host.query(
        "SELECT text FROM printers_responseline WHERE kind = 8"))  # fmt: skip
    assert "went on while the database was away" in notes
    history = host.query("SELECT outcome FROM jobs_historyentry")
    assert history == [("completed",)]


#: Three lines in one request: a script stream, closed by its end (not by an ok).
SCRIPT = "M117 first\nM117 second\nM117 third"


class CommandRig:
    """One simulated printer whose worker reaches PostgreSQL through a proxy; the
    test's own requests and reads go to PostgreSQL directly."""

    def __init__(self, tmp_path: Path) -> None:
        direct = postgres_url()
        self.host = Host(tmp_path, direct)
        self.host.migrate()
        self.record = self.host.add_simulated_printer("p1", sim_args="--time-scale 0")
        self.proxy = TcpProxy(("127.0.0.1", 5432))
        self.worker_side = Host(tmp_path, self.proxy.url(
            "postgresql", urlparse(direct).path, user="postgres"))  # fmt: skip

    @contextmanager
    def running(self) -> Iterator[None]:
        """The worker host, its printer ready; the proxy closed at the end."""
        try:
            with self.worker_side.running(web=False):
                wait_for(
                    lambda: self.host.query("SELECT state FROM printers_printer")
                    == [("idle",)],
                    60, "the printer to be ready",
                )  # fmt: skip
                yield
        finally:
            self.proxy.close()

    def ask(self, text: str) -> int:
        """Queue *text* as a request (as the API does); its row's id."""
        return int(self.host.shell(
            "from printers.models import Printer, QueuedCommand; print(QueuedCommand."
            f"objects.create(printer=Printer.objects.get(), text={text!r}).pk)"
        ).splitlines()[-1])  # fmt: skip

    def row(self, pk: int) -> tuple[str, str]:
        return self.host.query(
            f"SELECT state, reply FROM printers_queuedcommand WHERE id = {pk}"
        )[0]

    def answered(self, pk: int, state: str = "") -> Callable[[], bool]:
        """Whether the row ended (in *state*, if given)."""
        ends = (state,) if state else ("done", "failed")
        return lambda: self.row(pk)[0] in ends

    def ran(self) -> list[str]:
        """The M117 lines the firmware ran."""
        lines = self.record.read_text().splitlines()
        return [c for c in lines if c.startswith("M117")]


def test_a_command_runs_once_when_the_database_drops_as_the_worker_takes_it(
    tmp_path: Path,
):
    rig = CommandRig(tmp_path)
    with rig.running():
        # The worker's first write to the request table meets a dropped
        # connection: the database never sees it.
        rig.proxy.cut_at(b'UPDATE "printers_queuedcommand"', after_reply=False)
        script = rig.ask(SCRIPT)
        wait_for(rig.answered(script), 60, "the script to be answered")
        assert rig.proxy.blipped.is_set()
        # A request after it: were the script read again, it would run first.
        fence = rig.ask("M117 fence")
        wait_for(rig.answered(fence), 60, "the fence to be answered")
        log = rig.worker_side.log_tail(400)

    assert rig.row(script) == ("done", "ok"), log
    assert rig.ran() == ["M117 first", "M117 second", "M117 third", "M117 fence"]
    assert "the database does not answer" in log and "answers again" in log


def test_a_command_whose_taking_was_committed_unheard_fails_and_says_why(
    tmp_path: Path,
):
    """The database commits the worker's mark, and the answer is lost: the worker
    never acted on the row. Once the database is back the row fails, saying why,
    rather than wait for ever; nothing of it ran."""
    rig = CommandRig(tmp_path)
    with rig.running():
        # The mark's transaction commits; the answer to its COMMIT is lost.
        rig.proxy.cut_at(
            b'UPDATE "printers_queuedcommand"', after_reply=True, then=b"COMMIT"
        )
        script = rig.ask(SCRIPT)
        wait_for(rig.answered(script, "failed"), 60, "the script to fail")
        assert rig.proxy.blipped.is_set()
        fence = rig.ask("M117 fence")
        wait_for(rig.answered(fence, "done"), 60, "the fence to be answered")

    assert rig.row(script)[1] == (
        "error: the answer was lost while the database was away; ask again"
    )
    assert rig.ran() == ["M117 fence"]
