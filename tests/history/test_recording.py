"""A run's history entry is written when the run ends, by the worker's end-of-run
functions, with the figures of the file's analysis at the line reached (H1-H5 in
jobs/history.py)."""

from __future__ import annotations

import pytest

from jobs import history
from jobs.analysing import analysis_of
from jobs.history import HistoryEntry
from jobs.models import Job
from printers.worker import spool
from printers.worker.journal import Entry

pytestmark = pytest.mark.django_db


def entry_of(job: Job) -> HistoryEntry:
    return HistoryEntry.objects.get(job_number=job.pk)


def test_a_completed_run_records_the_whole_file_its_user_client_and_time(farm):
    job = farm.run(farm.p, "alice", "completed", minutes=42)

    entry = entry_of(job)
    analysed = analysis_of(job)
    assert entry.outcome == "completed"
    assert (entry.printer, entry.printer_slug, entry.name) == (farm.p, "p", "box.gcode")
    assert entry.sha256 == job.sha256 and len(entry.sha256) == 64
    assert (entry.user_name, entry.origin) == ("alice", "http:alice key")
    assert entry.started_at == job.started_at
    assert entry.finished_at == job.finished_at
    assert entry.print_seconds == pytest.approx(42 * 60, abs=5)
    assert entry.filament_used == pytest.approx(analysed.filament_total, abs=0.1)
    assert entry.filament_used > 100
    assert (entry.layer, entry.layers) == (10, 10)
    assert entry.metadata["layers"] == 10
    assert entry.metadata["slicer"] == "PrusaSlicer"


def test_an_aborted_run_counts_the_filament_and_layer_at_its_last_acked_line(farm):
    job = farm.job(farm.p, "alice")
    analysed = analysis_of(job)
    middle = analysed.layers[4].line + 10  # inside the fifth layer
    job = farm.end(
        farm.start(job, minutes_ago=5), "aborted", acked=middle, message="aborted"
    )

    entry = entry_of(job)
    assert entry.outcome == "aborted"
    assert entry.lines_acked == middle
    assert (entry.layer, entry.layers) == (5, 10)
    assert entry.filament_used == pytest.approx(analysed.filament_at(middle), abs=0.1)
    assert 0 < entry.filament_used < analysed.filament_total


def test_a_failed_run_keeps_the_firmware_message(farm):
    job = farm.start(farm.job(farm.p, "alice"), minutes_ago=2)
    before_first_layer = analysis_of(job).layers[0].line - 1
    job = farm.end(
        job, "failed", acked=before_first_layer, message="printer halted: MINTEMP"
    )

    entry = entry_of(job)
    assert (entry.outcome, entry.message) == ("failed", "printer halted: MINTEMP")
    assert entry.layer == 0  # before the first layer began


def test_a_job_that_cannot_start_is_a_failed_entry(farm):
    job = farm.start(farm.job(farm.p, "alice"), minutes_ago=0)

    spool.fail_job(job, "the job's file x.gcode is missing")

    entry = entry_of(job)
    assert entry.outcome == "failed"
    assert entry.message == "the job's file x.gcode is missing"
    assert entry.filament_used == 0


def test_a_dead_workers_run_becomes_an_interrupted_entry_at_the_journaled_line(farm):
    job = farm.start(farm.job(farm.p, "alice"), minutes_ago=20)
    analysed = analysis_of(job)
    line = analysed.layers[2].line + 1
    journaled = Entry(job_id=job.pk, sent=line + 4, acked=line, bytes_acked=900)

    spool.recover_interrupted(farm.p.pk, journaled)

    entry = entry_of(job)
    assert entry.outcome == "interrupted"
    assert entry.lines_acked == line
    assert entry.layer == 3
    assert "interrupted" in entry.message


def test_a_resumed_run_links_the_run_it_continues_and_counts_only_its_own_filament(
    farm,
):
    first = farm.job(farm.p, "alice")
    analysed = analysis_of(first)
    cut = analysed.layers[6].line
    first = farm.end(farm.start(first, minutes_ago=60), "interrupted", acked=cut)

    second = farm.end(farm.resume(first, cut, minutes=20), "completed")

    entry = entry_of(second)
    assert entry.resumed_from == first.pk
    assert entry.start_line == cut
    assert entry.outcome == "completed"
    assert (entry.layer, entry.layers) == (10, 10)
    rest = analysed.filament_total - analysed.filament_at(cut)
    assert entry.filament_used == pytest.approx(rest, abs=0.2)
    both = entry.filament_used + entry_of(first).filament_used
    assert both == pytest.approx(analysed.filament_total, abs=0.2)


def test_the_entry_outlives_the_job_deleted_through_the_api(farm):
    job = farm.run(farm.p, "alice", "completed")
    client = farm.client("alice")

    answer = client.post(f"/printer/job/p?a=delete&id={job.pk}")

    assert answer.status_code == 200, answer.content
    assert not Job.objects.filter(pk=job.pk).exists()
    entry = entry_of(job)
    assert (entry.name, entry.outcome, entry.user_name) == (
        "box.gcode",
        "completed",
        "alice",
    )
    listed = client.get("/printer/history").json()["data"]["runs"]
    assert [(r["job"], r["job_exists"]) for r in listed] == [(job.pk, False)]


def test_recording_a_run_twice_keeps_one_entry_with_the_latest_figures(farm):
    job = farm.run(farm.p, "alice", "aborted", acked=100)
    Job.objects.filter(pk=job.pk).update(lines_acked=200)

    history.record_run(job.pk)

    assert HistoryEntry.objects.filter(job_number=job.pk).count() == 1
    assert entry_of(job).lines_acked == 200


def test_the_same_job_row_run_again_from_the_admin_is_a_second_entry(farm):
    job = farm.run(farm.p, "alice", "aborted", acked=100, minutes=50)
    Job.objects.filter(pk=job.pk).update(
        state=Job.State.QUEUED, started_at=None, finished_at=None, lines_acked=0
    )

    farm.end(farm.start(Job.objects.get(pk=job.pk), minutes_ago=10), "completed")

    outcomes = HistoryEntry.objects.filter(job_number=job.pk).order_by("started_at")
    assert [e.outcome for e in outcomes] == ["aborted", "completed"]


def test_a_copy_to_the_sd_card_is_not_a_print_and_has_no_entry(farm):
    job = farm.job(farm.p, "alice")
    Job.objects.filter(pk=job.pk).update(kind=Job.Kind.SD_UPLOAD, sd_name="BOX.GCO")
    job = farm.start(Job.objects.get(pk=job.pk), minutes_ago=1)

    farm.end(job, "completed")

    assert not HistoryEntry.objects.filter(job_number=job.pk).exists()


def test_a_print_from_the_sd_card_has_an_entry_without_figures(farm):
    job = Job.objects.create(
        printer=farm.p,
        kind=Job.Kind.SD_PRINT,
        name="CUBE.GCO",
        sd_name="CUBE.GCO",
        uploaded_by=farm.users["alice"],
    )
    job = farm.start(job, minutes_ago=3)

    farm.end(job, "completed", acked=2)

    entry = entry_of(job)
    assert (entry.kind, entry.outcome, entry.sha256) == ("sd_print", "completed", "")
    assert (entry.filament_used, entry.layer, entry.layers) == (None, None, None)


def test_a_job_that_never_started_gets_no_entry(farm):
    job = farm.job(farm.p, "alice")

    assert history.record_run(job.pk) is None
    assert not HistoryEntry.objects.exists()
