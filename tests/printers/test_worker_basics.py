"""The worker against a Marlin simulator on a pty: jobs, waitstart, requests, replies."""

from __future__ import annotations

import contextlib
from functools import partial

import pytest
from django.db import OperationalError
from django.utils import timezone

from jobs.commands import request_action, send_command
from jobs.models import Job
from printers.models import Printer, QueuedCommand, ResponseLine
from printers.sample_gcode import commands_of, segments
from printers.worker.lease import DatabaseAway
from printers.worker.loop import PrinterWorker
from tests.conftest import job_lines, wait_for

pytestmark = pytest.mark.django_db


def state_of(job: Job) -> str:
    return Job.objects.get(pk=job.pk).state


@pytest.fixture
def marlin(sim_factory, make_printer):
    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "0")
    printer = make_printer(port=str(sim.link), baud=250000)
    worker = PrinterWorker(printer)
    worker.start()
    yield sim, printer, worker
    worker.stop()


def test_job_prints_then_printer_waits_for_a_clear_bed(marlin, make_job):
    sim, printer, worker = marlin
    first = make_job(printer, segments(50))
    second = make_job(printer, segments(20))

    wait_for(lambda: state_of(first) == "completed", 30, "job 1", step=worker.tick)
    for _ in range(20):
        worker.tick()

    wait_for(lambda: len(job_lines(sim)) >= 53, 5, "the record")
    assert job_lines(sim) == commands_of(segments(50))
    assert state_of(second) == "queued"
    assert Printer.objects.get(pk=printer.pk).state == Printer.State.WAITSTART
    request_action(printer, "bed_clear", origin="test")
    wait_for(lambda: state_of(second) == "completed", 30, "job 2", step=worker.tick)


def test_command_reply_comes_back_to_its_row(marlin):
    _, printer, worker = marlin
    row = send_command(printer, "M114", origin="test")

    wait_for(
        lambda: QueuedCommand.objects.get(pk=row.pk).state == "done", 10, "M114 done",
        step=worker.tick,
    )  # fmt: skip

    assert QueuedCommand.objects.get(pk=row.pk).reply == "ok"


def test_response_log_has_increasing_ids_and_filter_bits(marlin):
    _, printer, worker = marlin
    send_command(printer, "M105", origin="test")
    wait_for(
        lambda: ResponseLine.objects.filter(printer=printer, kind=2).exists(), 10,
        "an ack line", step=worker.tick,
    )  # fmt: skip
    worker.log.flush()

    lines = list(ResponseLine.objects.filter(printer=printer).order_by("seq"))
    seqs = [line.seq for line in lines]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    assert any(line.kind == 1 and line.text.endswith("M105") for line in lines)
    assert {line.kind for line in lines} <= {1, 2, 4, 8}


def test_pause_and_resume_keep_every_line_once(marlin, make_job):
    sim, printer, worker = marlin
    text = segments(400)
    job = make_job(printer, text)
    wait_for(lambda: worker.host.printing, 10, "the job to start", step=worker.tick)

    request_action(printer, "pause", origin="test")
    wait_for(lambda: state_of(job) == "paused", 10, "pause", step=worker.tick)
    request_action(printer, "resume", origin="test")
    wait_for(lambda: state_of(job) == "completed", 30, "the job", step=worker.tick)

    wait_for(lambda: len(job_lines(sim)) >= len(commands_of(text)), 5, "the record")
    assert job_lines(sim) == commands_of(text)


def test_abort_stops_the_job_and_says_who(marlin, make_job):
    sim, printer, worker = marlin
    job = make_job(printer, segments(5000))
    wait_for(lambda: worker.host.printing, 10, "the job to start", step=worker.tick)

    request_action(printer, "abort", origin="tester")
    wait_for(lambda: state_of(job) == "aborted", 10, "abort", step=worker.tick)

    job = Job.objects.get(pk=job.pk)
    assert job.message == "aborted by tester"
    assert job.lines_acked < 5003


def test_the_saved_progress_carries_the_time_it_was_saved(marlin, make_job):
    """The ETA is reckoned for the moment of the save (`Job.timing`)."""
    sim, printer, worker = marlin
    job = make_job(printer, segments(5000))
    saved = lambda: Job.objects.get(pk=job.pk)
    wait_for(lambda: saved().lines_acked > 0, 10, "a progress save", step=worker.tick)
    row = saved()
    assert row.started_at <= row.progress_at <= timezone.now()


def test_a_request_the_last_worker_took_and_never_answered_fails_with_the_reason(
    make_printer,
):
    """Taken (`sent`) before it is acted on, a request whose worker stopped first
    is never answered; the next worker tells its client why, instead of leaving it
    waiting for ever. Requests still pending are left for the poll."""
    printer = make_printer(port="/nonexistent")
    taken = QueuedCommand.objects.create(printer=printer, text="G28", state="sent")
    pending = QueuedCommand.objects.create(printer=printer, text="M114")

    worker = PrinterWorker(printer)
    worker.start()
    worker.stop()

    taken.refresh_from_db()
    assert taken.state == "failed"
    assert taken.reply == (
        "error: the printer's worker stopped before it answered; ask again"
    )
    assert QueuedCommand.objects.get(pk=pending.pk).state == "pending"


def answered_while_away(make_printer) -> tuple[PrinterWorker, QueuedCommand]:
    """An offline worker (as run_printer makes it: it keeps going while the
    database is away) that lost the database and holds a request's answer."""
    printer = make_printer(port="/nonexistent")
    worker = PrinterWorker(printer)
    worker.lease.keep_while_away = True  # run_printer holds the port's lock
    worker.start()
    worker.stay_offline = True
    row = QueuedCommand.objects.create(printer=printer, text="M114", state="sent")
    worker.lease.unreachable(OperationalError("server closed the connection"))
    answer = QueuedCommand.objects.filter(pk=row.pk).update
    worker.hold_or_run(partial(answer, state="done", reply="ok"))
    return worker, row


def test_an_offline_worker_writes_what_it_held_once_the_database_is_back(make_printer):
    """The database went away and came back while the printer was offline: what
    the worker held (here a request's answer) is written then, not only once the
    printer is back."""
    worker, row = answered_while_away(make_printer)
    assert worker.held, "the answer was written while the database was away"

    def tick() -> None:  # as run() does: the database away does not end the loop
        with contextlib.suppress(DatabaseAway):
            worker.tick()

    wait_for(
        lambda: QueuedCommand.objects.get(pk=row.pk).state == "done",
        10, "the held answer", step=tick,
    )  # fmt: skip
    assert not worker.held
    worker.stop()


def test_a_worker_stopped_once_the_database_is_back_writes_what_it_held_first(
    make_printer,
):
    """The database came back, and the worker is stopped before a turn wrote what
    it held: stop() writes it first. Left unwritten, the answer of a request the
    printer did answer would be failed by the next worker as never answered."""
    worker, row = answered_while_away(make_printer)
    printer = worker.printer
    assert worker.held

    worker.stop()

    row.refresh_from_db()
    assert (row.state, row.reply) == ("done", "ok")
    assert not worker.held
    assert Printer.objects.get(pk=printer.pk).lease_owner == ""


def test_a_worker_stopped_with_the_database_away_closes_its_port_and_says_so(
    make_printer, caplog
):
    """Still away at stop(): the port is closed all the same, nothing is written,
    and the log says what was left to the next worker."""
    printer = make_printer(port="/nonexistent")
    worker = PrinterWorker(printer)
    worker.lease.keep_while_away = True
    worker.start()
    worker.stay_offline = True
    worker.lease.unreachable(OperationalError("server closed the connection"))
    worker.hold_or_run(lambda: None)

    def refuse(now: float) -> None:
        raise worker.lease.unreachable(OperationalError("connection refused"))

    worker.lease.renew_now = refuse
    with caplog.at_level("WARNING", logger="printhost.worker"):
        worker.stop()

    assert worker.transport is None
    assert len(worker.held) == 1
    assert "stopped with the database away" in caplog.text
    assert "1 other writes were not stored" in caplog.text
