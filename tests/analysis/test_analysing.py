"""Analysis rows in the database: asked for on every stored file, run once, safe to
run twice, and picked up again after a worker dies (Celery itself is in
test_celery_worker.py; here `run` is called as the task calls it)."""

from __future__ import annotations

import base64
from datetime import timedelta
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
from django.db import transaction
from django.utils import timezone

from jobs import analysing, analysis_task
from jobs.analysis.thumbnails import png_encode
from jobs.models import FileAnalysis, Job
from jobs.services import reprint

if TYPE_CHECKING:
    from collections.abc import Callable

    from printers.models import Printer

DATA = Path(__file__).resolve().parent.parent / "data"
SQUARE = "G28\nM83\nG1 Z0.2 F600\nG1 X10 E1 F1200\nG1 Y10 E1\nG1 X0 E1\nG1 Y0 E1\n"


def png_block(width: int, height: int) -> str:
    text = base64.b64encode(png_encode(width, height, b"\x80" * (4 * width * height)))
    return f"; thumbnail begin {width}x{height} {len(text)}\n; {text.decode()}\n; thumbnail end\n"


@pytest.fixture
def printer(make_printer: Callable[..., Printer]) -> Printer:
    return make_printer(slug="mk4")


@pytest.fixture
def sent(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Analyses handed to the broker (the real send, minus the broker)."""
    handed: list[int] = []
    monkeypatch.setattr(
        "jobs.tasks.analyse_file.delay", lambda pk: handed.append(pk), raising=True
    )
    return handed


def test_every_stored_file_asks_for_one_analysis_per_file_and_profile(
    printer: Printer, make_printer: Callable[..., Printer], make_job: Callable,
    sent: list[int], django_capture_on_commit_callbacks: Callable,
) -> None:  # fmt: skip
    with django_capture_on_commit_callbacks(execute=True):
        first = make_job(printer, SQUARE)
        second = make_job(printer, SQUARE, name="again.gcode")
        again = reprint(first)
    assert first.analysis_id == second.analysis_id == again.analysis_id
    assert sent == [first.analysis_id]
    assert FileAnalysis.objects.get().state == FileAnalysis.State.PENDING
    other = make_printer(slug="fast", motion_profile={"print_acceleration": 9000})
    with django_capture_on_commit_callbacks(execute=True):
        elsewhere = make_job(other, SQUARE)
    assert elsewhere.analysis_id != first.analysis_id
    assert FileAnalysis.objects.count() == 2
    assert sent[-1] == elsewhere.analysis_id


def test_nothing_is_sent_when_the_upload_rolls_back(
    printer: Printer, make_job: Callable, sent: list[int],
    django_capture_on_commit_callbacks: Callable,
) -> None:  # fmt: skip
    with django_capture_on_commit_callbacks(execute=True):
        try:
            with transaction.atomic():
                make_job(printer, SQUARE)
                raise RuntimeError("the request failed after storing")
        except RuntimeError:
            pass
    assert sent == []


def test_a_run_stores_the_result_and_thumbnails_and_a_second_run_does_nothing(
    printer: Printer, make_job: Callable, settings: object
) -> None:
    job = make_job(printer, png_block(16, 12) + png_block(64, 48) + SQUARE)
    assert analysis_task.run(job.analysis_id) == "done"
    row = FileAnalysis.objects.get(pk=job.analysis_id)
    assert row.state == FileAnalysis.State.DONE
    assert row.attempts == 1
    assert row.reason == ""
    result = analysing.analysis_of(Job.objects.get(pk=job.pk))
    assert result is not None
    assert result.commands == job.line_count
    assert result.filament_total == pytest.approx(4)
    assert [t["name"] for t in result.thumbnails] == ["64x48.png", "16x12.png"]
    folder = Path(settings.ANALYSIS_DIR) / job.sha256  # type: ignore[attr-defined]
    assert (folder / "64x48.png").read_bytes().startswith(b"\x89PNG")
    assert analysis_task.run(job.analysis_id) == "skipped"
    assert FileAnalysis.objects.get(pk=job.analysis_id).attempts == 1


def test_a_busy_analysis_is_left_alone_until_its_worker_falls_silent(
    printer: Printer, make_job: Callable, sent: list[int]
) -> None:
    job = make_job(printer, SQUARE)
    assert analysis_task.claim(job.analysis_id, "host:1")
    assert analysis_task.run(job.analysis_id, worker="host:2") == "skipped"
    assert analysing.sweep() == 0
    # The first worker dies: its heartbeat ages past the limit.
    FileAnalysis.objects.filter(pk=job.analysis_id).update(
        heartbeat_at=timezone.now() - timedelta(minutes=5), sent_at=timezone.now()
    )
    assert analysing.sweep() == 1
    assert sent == [job.analysis_id]
    assert analysis_task.run(job.analysis_id, worker="host:2") == "done"
    row = FileAnalysis.objects.get(pk=job.analysis_id)
    assert (row.state, row.worker, row.attempts) == ("done", "host:2", 2)


def test_the_sweep_resends_what_never_reached_the_broker(
    printer: Printer, make_job: Callable, sent: list[int]
) -> None:
    job = make_job(printer, SQUARE)
    assert FileAnalysis.objects.get(pk=job.analysis_id).sent_at is None
    assert analysing.sweep() == 1
    assert sent == [job.analysis_id]
    assert FileAnalysis.objects.get(pk=job.analysis_id).sent_at is not None
    assert analysing.sweep() == 0


def test_a_file_gone_from_storage_fails_with_the_reason(
    printer: Printer, make_job: Callable
) -> None:
    job = make_job(printer, SQUARE)
    job.path.unlink()
    assert analysis_task.run(job.analysis_id) == "failed"
    row = FileAnalysis.objects.get(pk=job.analysis_id)
    assert row.reason == "no stored file has this SHA-256 any more"


def test_a_file_changed_on_disk_fails_instead_of_describing_other_bytes(
    printer: Printer, make_job: Callable
) -> None:
    job = make_job(printer, SQUARE)
    job.path.write_text(SQUARE + "G1 X50\n")
    assert analysis_task.run(job.analysis_id) == "failed"
    assert "changed" in FileAnalysis.objects.get(pk=job.analysis_id).reason


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("M117 no moves here\nM105\n", "the file has no moves"),
        (
            "; thumbnail begin 16x16 8\n; !!!!\n; thumbnail end\n" + SQUARE,
            "broken base64",
        ),
    ],
)
def test_a_partial_analysis_says_why_and_the_job_still_prints(
    printer: Printer, make_job: Callable, text: str, reason: str
) -> None:
    job = make_job(printer, text)
    assert analysis_task.run(job.analysis_id) == "done"
    row = FileAnalysis.objects.get(pk=job.analysis_id)
    assert reason in row.reason
    assert Job.objects.get(pk=job.pk).state == Job.State.QUEUED


def test_a_crash_inside_the_analyser_fails_the_row_not_the_worker(
    printer: Printer, make_job: Callable, monkeypatch: pytest.MonkeyPatch
) -> None:
    job = make_job(printer, SQUARE)

    def broken(self: object, data: bytes) -> None:
        raise TypeError("a bug")

    monkeypatch.setattr("jobs.analysis.analyser.Analyser.feed", broken)
    assert analysis_task.run(job.analysis_id) == "failed"
    assert FileAnalysis.objects.get(pk=job.analysis_id).reason == "TypeError: a bug"


def test_the_printers_profile_and_materials_reach_the_analysis(
    make_printer: Callable[..., Printer], make_job: Callable
) -> None:
    slow = make_printer(
        slug="slow", motion_profile={"max_feedrate": [5, 5, 5, 25]},
        filament_density=2.0,
    )  # fmt: skip
    fast = make_printer(slug="fast")
    jobs = [make_job(printer, SQUARE) for printer in (slow, fast)]
    for job in jobs:
        analysis_task.run(job.analysis_id)
    slow_result, fast_result = (
        analysing.analysis_of(Job.objects.get(pk=job.pk)) for job in jobs
    )
    assert slow_result and fast_result
    assert slow_result.motion_seconds > 2 * fast_result.motion_seconds
    assert slow_result.filament_weight_g > fast_result.filament_weight_g


def test_a_grbl_printer_gets_a_cnc_analysis(
    make_printer: Callable[..., Printer], make_job: Callable
) -> None:
    router = make_printer(slug="router", firmware="grbl")
    job = make_job(router, "G21 G90\nM3 S9000\nG0 X10\nG1 Y10 F300\nM5\n")
    analysis_task.run(job.analysis_id)
    result = analysing.analysis_of(Job.objects.get(pk=job.pk))
    assert result and result.kind == "cnc"
    assert result.spindle_max == 9000


def test_real_slicer_files_are_analysed_from_storage(
    printer: Printer, make_job: Callable
) -> None:
    job = make_job(
        printer, (DATA / "prusaslicer-2.5_box-and-cylinder.gcode").read_text()
    )
    analysis_task.run(job.analysis_id)
    result = analysing.analysis_of(Job.objects.get(pk=job.pk))
    assert result is not None
    assert len(result.layers) == 50
    assert result.slicer["slicer"] == "PrusaSlicer"


def test_a_finished_analysis_is_read_once_per_process(
    printer: Printer, make_job: Callable, django_assert_num_queries: Callable
) -> None:
    """A running job's ETA is asked for on every progress write: its result column
    (megabytes for a big file) is loaded and parsed once, not each time."""
    job = make_job(printer, SQUARE)
    analysis_task.run(job.analysis_id)

    def fresh() -> Job:
        return (
            Job.objects.select_related("analysis")
            .defer("analysis__result")
            .get(pk=job.pk)
        )

    first = analysing.analysis_of(fresh())
    again = fresh()
    with django_assert_num_queries(0):
        assert analysing.analysis_of(again) is first


def test_a_number_too_large_to_store_fails_the_row_instead_of_retrying_for_ever(
    printer: Printer, make_job: Callable
) -> None:
    """An inf or a NaN (a 400-digit coordinate, `estimated printing time = nan`)
    is no JSON the database takes: the row stayed running and was analysed again
    and again."""
    job = make_job(printer, "; filament_diameter = 1e999\n" + SQUARE)
    assert analysis_task.run(job.analysis_id) == "failed"
    row = FileAnalysis.objects.get(pk=job.analysis_id)
    assert (row.state, row.reason) == (
        "failed", "the file holds a number too large to work with (inf or NaN)"
    )  # fmt: skip


def test_one_note_said_many_times_is_kept_once(
    printer: Printer, make_job: Callable
) -> None:
    broken = "; thumbnail begin 16x16 8\n; !!!!\n; thumbnail end\n"
    job = make_job(printer, broken * 50 + SQUARE)
    assert analysis_task.run(job.analysis_id) == "done"
    reason = FileAnalysis.objects.get(pk=job.analysis_id).reason
    assert reason.count("broken base64") == 1


def test_an_analysis_that_never_finishes_is_not_started_a_fourth_time(
    printer: Printer, make_job: Callable
) -> None:
    """Its worker killed each time (out of memory): it would only stop again."""
    job = make_job(printer, SQUARE)
    FileAnalysis.objects.filter(pk=job.analysis_id).update(attempts=3)
    assert analysis_task.run(job.analysis_id) == "failed"
    reason = FileAnalysis.objects.get(pk=job.analysis_id).reason
    assert reason.startswith("started 3 times without finishing")


def test_a_tool_number_no_machine_has_is_not_a_tool(
    printer: Printer, make_job: Callable
) -> None:
    """Each tool gets its filament, flow and heater: T4000000000 filled memory."""
    text = "T10000000\nM221 T20000000 S90\nM104 T30000000 S200\n" + SQUARE
    job = make_job(printer, text)
    assert analysis_task.run(job.analysis_id) == "done"
    result = FileAnalysis.objects.get(pk=job.analysis_id).result
    assert result["tools"] == [] and len(result["filament_mm"]) == 1


def test_at_most_sixteen_thumbnails_are_kept(printer: Printer, make_job: Callable):
    """Each is listed in every job dict of the file: 500,000 tiny ones made 70 MB."""
    pictures = "".join(png_block(size, size) for size in range(1, 31))
    job = make_job(printer, pictures + SQUARE)
    assert analysis_task.run(job.analysis_id) == "done"
    row = FileAnalysis.objects.get(pk=job.analysis_id)
    assert len(row.result["thumbnails"]) == 16
    assert row.reason == "more than 16 thumbnails: the rest were skipped"
