# ruff: noqa: RUF001 (reasons print sizes with the multiplication sign)
"""The farm queue in one process on SQLite: storing, waiting with a reason, routing,
the queue's order, and the claim's conditional update."""

from __future__ import annotations

import io
from datetime import timedelta
from typing import TYPE_CHECKING

import pytest
from django.utils import timezone

from jobs.farm.dispatch import PRINTER_TAKEN, Dispatcher, claim
from jobs.farm.models import FarmJob
from jobs.farm.requirements import BadRequirement, Requirements
from jobs.farm.storing import NotWaiting, cancel, change, store_farm_upload
from jobs.gcode import BadGcode
from jobs.models import FileAnalysis, Job
from printers.models import Printer
from tests.farm.conftest import BIG, box_gcode, make_ready

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

pytestmark = pytest.mark.django_db

SMALL = box_gcode(100, 50, 30)


def jobs_of(printer: Printer) -> list[Job]:
    return list(Job.objects.filter(printer=printer))


def test_an_upload_is_stored_once_in_the_farm_folder_and_waits_for_its_analysis(
    storage: Path, to_farm: Callable[..., FarmJob]
) -> None:
    farm_job = to_farm(SMALL, analyse=False, material="PETG")

    assert farm_job.file.startswith("farm/") and farm_job.path.read_text() == SMALL
    assert farm_job.state == FarmJob.State.WAITING
    assert farm_job.reason == "waiting for the file's analysis"
    assert farm_job.analysis.state == FileAnalysis.State.PENDING
    assert farm_job.line_count == SMALL.count("\n") and farm_job.material == "PETG"
    assert list((storage / "farm").iterdir()) == [farm_job.path]


def test_a_file_that_fails_the_upload_checks_leaves_nothing(storage: Path) -> None:
    with pytest.raises(BadGcode, match="holds no G-code command"):
        store_farm_upload(
            io.BytesIO(b"; only a comment\n"), name="empty.gcode",
            requirements=Requirements(),
        )  # fmt: skip
    assert not FarmJob.objects.exists()
    assert list((storage / "farm").iterdir()) == []


def test_a_job_without_its_analysis_waits_for_it_even_with_a_free_printer(
    farm_printer: Callable[..., Printer], to_farm: Callable[..., FarmJob]
) -> None:
    printer = farm_printer("mk3")
    farm_job = to_farm(SMALL, analyse=False)

    assert Dispatcher().run_pass() == 0
    farm_job.refresh_from_db()
    assert farm_job.state == FarmJob.State.WAITING
    assert farm_job.reason == "waiting for the file's analysis"
    assert jobs_of(printer) == []


def test_an_analysed_job_becomes_a_normal_queued_job_on_a_matching_printer(
    storage: Path,
    farm_printer: Callable[..., Printer],
    to_farm: Callable[..., FarmJob],
) -> None:
    farm_printer("pla", material="PLA")
    petg = farm_printer("petg", material="PETG")
    farm_job = to_farm(SMALL, material="petg")
    farm_file = farm_job.path

    assert Dispatcher().run_pass() == 1

    farm_job.refresh_from_db()
    (job,) = jobs_of(petg)
    assert farm_job.state == FarmJob.State.ASSIGNED and farm_job.reason == ""
    assert (farm_job.job_id, farm_job.printer_id) == (job.pk, petg.pk)
    assert job.state == Job.State.QUEUED and job.name == "part.gcode"
    assert job.path.read_text() == SMALL and job.path.parent == storage / "petg"
    assert (job.sha256, job.line_count) == (farm_job.sha256, farm_job.line_count)
    assert job.analysis is not None  # asked for the printer's own profile
    assert job.origin.startswith(f"farm job {farm_job.pk}")
    # The printer's job holds the file now; the farm's copy is gone.
    assert not farm_file.exists() and farm_job.file == ""
    assert Dispatcher().run_pass() == 0
    assert Job.objects.count() == 1


def test_a_job_no_printer_can_take_waits_and_says_why(
    farm_printer: Callable[..., Printer], to_farm: Callable[..., FarmJob]
) -> None:
    farm_printer("mk3", material="PLA")
    petg = to_farm(SMALL, material="PETG")
    huge = to_farm(box_gcode(240, 200, 220), name="tall.gcode")

    Dispatcher().run_pass()

    petg.refresh_from_db()
    huge.refresh_from_db()
    assert petg.reason == "no printer has PETG loaded"
    assert huge.reason == "the part (240×200×219.8 mm) fits no printer's build volume"
    assert not Job.objects.exists()


def test_busy_printers_are_named_with_what_keeps_them(
    farm_printer: Callable[..., Printer],
    make_job: Callable[..., Job],
    to_farm: Callable[..., FarmJob],
) -> None:
    farm_printer("a-printing", state=Printer.State.PRINTING)
    farm_printer("b-bed", state=Printer.State.WAITSTART)
    queued = farm_printer("c-queued")
    make_job(queued, "G28\n")
    farm_printer("d-dead", lease_expires_at=timezone.now() - timedelta(seconds=1))
    farm_job = to_farm(SMALL)

    Dispatcher().run_pass()

    farm_job.refresh_from_db()
    assert farm_job.reason == (
        "every matching printer is busy: a-printing printing, b-bed waiting for its "
        "bed to be cleared, c-queued has a job queued, d-dead offline (no worker "
        "holds it)"
    )


def test_the_smallest_fitting_volume_is_preferred_then_the_printer_idle_longest(
    farm_printer: Callable[..., Printer], to_farm: Callable[..., FarmJob]
) -> None:
    big = farm_printer("big", build_volume=BIG)
    recent = farm_printer("mk3-recent")
    idle = farm_printer("mk3-idle")
    for printer, hours in ((recent, 1), (idle, 5)):
        Job.objects.create(
            printer=printer, name="old", state=Job.State.COMPLETED,
            finished_at=timezone.now() - timedelta(hours=hours),
        )  # fmt: skip
    first, second, third = (to_farm(SMALL, name=f"{n}.gcode") for n in "abc")
    to_farm(box_gcode(100, 100, 300), name="tall.gcode", priority=5)

    assert Dispatcher().run_pass() == 3

    where = dict(FarmJob.objects.values_list("name", "printer__slug"))
    # First by priority, and only the big one fits it; had "c" gone before it, the
    # big printer would have taken "c" once both MK3s were given a job.
    assert where["tall.gcode"] == "big"
    assert (where["a.gcode"], where["b.gcode"]) == ("mk3-idle", "mk3-recent")
    third.refresh_from_db()
    assert third.state == FarmJob.State.WAITING
    assert "every matching printer is busy" in third.reason
    assert jobs_of(big)[0].name == "tall.gcode"


def test_the_queue_goes_by_priority_then_deadline_then_age(
    to_farm: Callable[..., FarmJob],
) -> None:
    soon = timezone.now() + timedelta(hours=1)
    later = soon + timedelta(hours=1)
    old = to_farm(SMALL, name="old.gcode", analyse=False)
    late = to_farm(SMALL, name="late.gcode", analyse=False, deadline=later)
    urgent = to_farm(SMALL, name="urgent.gcode", analyse=False, deadline=soon)
    low = to_farm(SMALL, name="low.gcode", analyse=False, priority=-1, deadline=soon)
    high = to_farm(SMALL, name="high.gcode", analyse=False, priority=3)

    order = list(FarmJob.objects.filter(state="waiting").values_list("pk", flat=True))
    assert order == [high.pk, urgent.pk, late.pk, old.pk, low.pk]


def test_a_claim_gives_a_job_once_and_a_printer_one_job(
    farm_printer: Callable[..., Printer], to_farm: Callable[..., FarmJob]
) -> None:
    one, two = farm_printer("one"), farm_printer("two")
    first, second = to_farm(SMALL, name="a.gcode"), to_farm(SMALL, name="b.gcode")

    assert claim(first.pk, one.pk).job is not None
    again = claim(first.pk, two.pk)  # the job is no longer waiting
    assert again.job is None and again.lost == "job"
    busy = claim(second.pk, one.pk)  # the printer has a queued job now
    assert busy.job is None and busy.lost == PRINTER_TAKEN
    second.refresh_from_db()
    assert second.state == FarmJob.State.WAITING  # the refused claim rolled back
    assert [j.name for j in jobs_of(one)] == ["a.gcode"] and jobs_of(two) == []


def test_a_claim_rechecks_the_printer_it_reads_under_the_claim(
    farm_printer: Callable[..., Printer], to_farm: Callable[..., FarmJob]
) -> None:
    printer = farm_printer("mk3")
    farm_job = to_farm(SMALL, material="PLA")
    # The operator loads PETG between the pass's read and the claim.
    Printer.objects.filter(pk=printer.pk).update(material="PETG")

    assert claim(farm_job.pk, printer.pk).lost == PRINTER_TAKEN
    assert not Job.objects.exists()


def test_a_failed_claim_leaves_no_file_in_the_printers_storage(
    storage: Path,
    farm_printer: Callable[..., Printer],
    to_farm: Callable[..., FarmJob],
) -> None:
    printer = farm_printer("mk3")
    farm_job = to_farm(SMALL)

    def fail(farm_job: FarmJob, printer: Printer) -> None:
        raise RuntimeError("killed mid-claim")

    with pytest.raises(RuntimeError):
        claim(farm_job.pk, printer.pk, hook=fail)
    farm_job.refresh_from_db()
    assert farm_job.state == FarmJob.State.WAITING and farm_job.path.is_file()
    assert not any((storage / "mk3").glob("*"))
    assert claim(farm_job.pk, printer.pk).job is not None


def test_cancel_and_change_act_only_on_a_waiting_job(
    farm_printer: Callable[..., Printer], to_farm: Callable[..., FarmJob]
) -> None:
    farm_printer("mk3")
    waiting = to_farm(box_gcode(90, 50, 30), name="a.gcode", analyse=False)
    given = to_farm(SMALL, name="b.gcode")
    Dispatcher().run_pass()
    given.refresh_from_db()

    changed = change(waiting, {"material": "PETG", "nozzle": 0.6, "priority": 2})
    assert (changed.material, changed.nozzle_diameter, changed.priority) == (
        "PETG", 0.6, 2,
    )  # fmt: skip
    with pytest.raises(BadRequirement, match="cannot change name"):
        change(waiting, {"name": "x"})
    with pytest.raises(BadRequirement, match="deadline must be an ISO 8601 time"):
        change(waiting, {"deadline": "tomorrow"})
    with pytest.raises(NotWaiting, match="already given to mk3"):
        change(given, {"priority": 1})
    with pytest.raises(NotWaiting, match="already given to mk3"):
        cancel(given)
    waiting.refresh_from_db()
    assert waiting.priority == 2 and waiting.deadline is None

    path = waiting.path
    cancel(waiting)
    waiting.refresh_from_db()
    assert waiting.state == FarmJob.State.CANCELLED and not path.exists()
    assert Dispatcher().run_pass() == 0


def test_a_grbl_machine_takes_no_farm_job(
    farm_printer: Callable[..., Printer], to_farm: Callable[..., FarmJob]
) -> None:
    farm_printer("router", firmware=Printer.Firmware.GRBL)
    farm_job = to_farm(SMALL)
    Dispatcher().run_pass()
    farm_job.refresh_from_db()
    assert farm_job.reason == "no printer takes farm jobs (turn on “farm” on a printer)"


def test_a_dead_worker_keeps_its_printer_from_the_farm(
    farm_printer: Callable[..., Printer], to_farm: Callable[..., FarmJob]
) -> None:
    printer = farm_printer("mk3")
    make_ready(printer, lease_expires_at=None)
    to_farm(SMALL)
    assert Dispatcher().run_pass() == 0


def test_a_job_whose_analysis_row_was_removed_asks_for_it_again(
    farm_printer: Callable[..., Printer], to_farm: Callable[..., FarmJob]
) -> None:
    farm_printer("mk3")
    farm_job = to_farm(SMALL, analyse=False)
    FileAnalysis.objects.all().delete()  # as the upkeep would, wrongly

    assert Dispatcher().run_pass() == 0
    farm_job.refresh_from_db()
    assert farm_job.analysis.state == FileAnalysis.State.PENDING
    assert farm_job.reason == "waiting for the file's analysis"


def test_a_job_whose_file_cannot_be_given_waits_saying_why_and_the_next_one_goes(
    farm_printer: Callable[..., Printer], to_farm: Callable[..., FarmJob]
) -> None:
    """One farm job's broken file (removed outside printhost, a full disk) is that
    job's problem: the pass goes on to the jobs behind it."""
    farm_printer("mk3a")
    farm_printer("mk3b")
    broken = to_farm(SMALL, priority=5)
    fine = to_farm(box_gcode(60, 40, 10))
    broken.path.unlink()

    assert Dispatcher().run_pass() == 1
    broken.refresh_from_db()
    fine.refresh_from_db()
    assert fine.state == FarmJob.State.ASSIGNED
    assert broken.state == FarmJob.State.WAITING
    assert "could not be given to mk3" in broken.reason
    assert "No such file" in broken.reason


def test_a_job_behind_more_than_a_batch_of_waiting_ones_still_gets_a_free_printer(
    farm_printer: Callable[..., Printer], to_farm: Callable[..., FarmJob]
) -> None:
    """600 jobs ahead of it wait for their analysis; the pass reads the whole
    queue, so the analysed one behind them is given to the free printer."""
    printer = farm_printer("mk3")
    ahead = to_farm(SMALL, analyse=False, priority=5)
    same = {"sha256": ahead.sha256, "analysis": ahead.analysis, "priority": 5}
    FarmJob.objects.bulk_create(
        FarmJob(name=f"ahead-{n}.gcode", reason=ahead.reason, **same)
        for n in range(599)
    )
    behind = to_farm(box_gcode(60, 40, 10))

    assert Dispatcher().run_pass() == 1
    behind.refresh_from_db()
    assert behind.state == FarmJob.State.ASSIGNED and behind.printer == printer
    assert FarmJob.objects.filter(state=FarmJob.State.WAITING).count() == 600
