"""The job journal: a SIGKILLed worker's job resumes its record at the exact acked line."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from printers.sample_gcode import commands_of, segments
from printers.worker.journal import SLOT, Entry, Journal
from tests.conftest import HOST_COMMANDS, wait_for
from tests.hosts import Host

pytestmark = pytest.mark.slow


def test_journal_keeps_the_newest_entry_in_a_file_of_two_slots(tmp_path):
    journal = Journal(7, tmp_path)
    journal.start_job()
    for acked in range(10, 31):
        journal.record(Entry(3, acked, acked + 4, acked * 20))
    journal.record(Entry(3, 30, 34, 600))  # a repeat writes nothing

    assert Journal(7, tmp_path).last() == Entry(3, 30, 34, 600)
    assert journal.path.stat().st_size == 2 * SLOT  # written in place, never grown
    journal.close()


def test_a_torn_slot_leaves_the_entry_before_it(tmp_path):
    journal = Journal(7, tmp_path)
    journal.start_job()
    journal.record(Entry(3, 10, 14, 200))
    journal.record(Entry(3, 12, 16, 240))
    journal.close()
    data = bytearray(journal.path.read_bytes())
    newest = data.index(b"3 12 16 240 ")
    # The process died in the middle of storing the newest entry: part of the
    # slot holds the new digits, the rest the old.
    data[newest + 2 : newest + 4] = b"99"
    journal.path.write_bytes(bytes(data))

    assert Journal(7, tmp_path).last() == Entry(3, 10, 14, 200)


def test_a_journal_of_the_earlier_format_gives_its_last_whole_line(tmp_path):
    journal = Journal(7, tmp_path)
    journal.path.write_text("3 10 14 200\n3 12 16 240\n3 99 1")

    assert journal.last() == Entry(3, 12, 16, 240)
    journal.start_job()  # the next job writes the new format over it
    journal.record(Entry(4, 1, 2, 30))
    assert Journal(7, tmp_path).last() == Entry(4, 1, 2, 30)
    journal.close()


def test_sigkilled_worker_job_is_interrupted_at_exactly_the_last_acked_line(
    tmp_path: Path, sim_factory
):
    sim = sim_factory("marlin", "--time-scale", "0", "--baud", "250000")
    host = Host(tmp_path)
    host.env["PRINTHOST_LEASE_SECONDS"] = "2"
    host.migrate()
    host.shell(
        "from printers.models import Printer; Printer.objects.create(name='P0', "
        f"slug='p0', port={str(sim.link)!r}, baud=250000, temperature_interval=0)"
    )
    text = segments(20000)
    (tmp_path / "job.gcode").write_text(text)
    host.manage("add_job", "p0", str(tmp_path / "job.gcode"))
    journal = Journal(1, tmp_path / "journal")
    journaled = lambda: (journal.last() or Entry(0, 0, 0, 0)).acked
    ran = lambda: [c for c in sim.executed() if not c.startswith(HOST_COMMANDS)]

    first = host.run_printer("p0")
    try:
        wait_for(lambda: journaled() > 500, 60, "the job to be well under way")
        # The firmware stops finishing commands (no more oks); the worker reads the
        # oks already sent, and is killed the moment its journal has the last one.
        # The record is flushed every 50 ms: it counts only once it holds every
        # command the firmware's own counter has (host commands included).
        assert sim.control("busy 600") == "ok"
        wait_for(
            lambda: len(sim.executed()) == sim.stats()["executed"]
            and journaled() == len(ran()) and journaled() > 0, 30,
            "the worker to journal every ok the firmware sent",
        )  # fmt: skip
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=30)
    finally:
        if first.poll() is None:
            first.kill()
    executed = len(ran())
    saved = host.query("SELECT lines_acked FROM jobs_job")[0][0]

    wait_for(lambda: host.lease_expired(), 30, "the dead worker's lease to expire")
    second = host.run_printer("p0")
    try:
        state = lambda: host.query("SELECT state, lines_acked, message FROM jobs_job")[
            0
        ]
        wait_for(lambda: state()[0] == "interrupted", 60, "the job to be interrupted")
    finally:
        second.send_signal(signal.SIGTERM)
        second.wait(timeout=60)

    job_state, lines_acked, message = state()
    print(f"executed {executed}, journaled {journaled()}, saved in the DB {saved}")
    assert ran() == commands_of(text)[:executed], "a line was repeated or skipped"
    assert lines_acked == executed
    assert f"at line {executed} of 20003" in message
    assert os.path.getsize(journal.path) < 1 << 21
