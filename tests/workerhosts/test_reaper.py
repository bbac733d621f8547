"""A silent worker's printer is shown offline and its run interrupted; nobody is
handed the printer; the host's journal corrects the line when it is back."""

from __future__ import annotations

from datetime import timedelta

import pytest
from django.utils import timezone

from jobs.models import Job
from printers.hosts import WorkerHost
from printers.models import Printer
from printers.reaper import reap_silent_workers
from printers.worker import spool
from printers.worker.journal import Entry

pytestmark = pytest.mark.django_db

GCODE = "".join(f"G1 X{i % 100} Y{i % 50} F3000\n" for i in range(300))


def _printing(make_printer, make_job, *, expires_in: float, **fields) -> Job:
    printer = make_printer(**fields)
    job = make_job(printer, GCODE)
    Job.objects.filter(pk=job.pk).update(state=Job.State.PRINTING, lines_acked=120)
    Printer.objects.filter(pk=printer.pk).update(
        state=Printer.State.PRINTING,
        lease_owner="shelf:42:abcdef",
        lease_expires_at=timezone.now() + timedelta(seconds=expires_in),
    )
    return Job.objects.get(pk=job.pk)


def test_a_printer_whose_lease_ran_out_is_offline_and_its_run_interrupted(
    make_printer, make_job
):
    host = WorkerHost.objects.create(name="shelf-1")
    job = _printing(make_printer, make_job, expires_in=-1, worker_host=host)
    assert reap_silent_workers() == [job.printer_id]
    printer = Printer.objects.get(pk=job.printer_id)
    assert printer.state == Printer.State.OFFLINE
    assert "worker host shelf-1 stopped answering" in printer.state_message
    assert printer.lease_owner == "shelf:42:abcdef"  # handed to nobody
    job.refresh_from_db()
    assert job.state == Job.State.INTERRUPTED
    assert "at line 120 of 300 as last saved" in job.message
    assert reap_silent_workers() == []  # once


def test_a_live_lease_is_left_alone(make_printer, make_job):
    job = _printing(make_printer, make_job, expires_in=5)
    assert reap_silent_workers() == []
    assert Job.objects.get(pk=job.pk).state == Job.State.PRINTING


def test_a_worker_that_renews_during_the_reaping_keeps_its_run(
    make_printer, make_job, monkeypatch
):
    job = _printing(make_printer, make_job, expires_in=-1)
    real = Printer.objects.filter

    def renewed_meanwhile(*args, **kwargs):
        if "lease_expires_at" in kwargs:  # the reaper's conditional update
            Printer.objects.filter(pk=job.printer_id).update(
                lease_expires_at=timezone.now() + timedelta(seconds=10)
            )
        return real(*args, **kwargs)

    monkeypatch.setattr(Printer.objects, "filter", renewed_meanwhile)
    assert reap_silent_workers() == []
    monkeypatch.undo()
    assert Job.objects.get(pk=job.pk).state == Job.State.PRINTING
    assert Printer.objects.get(pk=job.printer_id).state == Printer.State.PRINTING


def test_the_hosts_next_worker_takes_the_exact_line_from_its_journal(
    make_printer, make_job
):
    job = _printing(make_printer, make_job, expires_in=-1)
    reap_silent_workers()
    recovered = spool.recover_interrupted(
        job.printer_id, Entry(job.pk, acked=131, sent=135, bytes_acked=2000)
    )
    assert [j.pk for j in recovered] == [job.pk]
    job.refresh_from_db()
    assert (job.state, job.lines_acked, job.lines_sent) == ("interrupted", 131, 135)
    assert "at line 131 of 300" in job.message and "as last saved" not in job.message


def test_a_reaped_run_keeps_the_printer_waiting_for_a_clear_bed_even_without_journal(
    make_printer, make_job
):
    job = _printing(make_printer, make_job, expires_in=-1)
    reap_silent_workers()
    recovered = spool.recover_interrupted(job.printer_id, None)
    assert [j.pk for j in recovered] == [job.pk]  # the worker goes to waitstart
    job.refresh_from_db()
    assert job.lines_acked == 120 and "at line 120 of 300" in job.message
    assert spool.recover_interrupted(job.printer_id, None) == []  # seen once
