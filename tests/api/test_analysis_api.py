"""A job's analysis through the API: figures, layers, thumbnails, ETA by time."""

from __future__ import annotations

import base64
from datetime import timedelta
from pathlib import Path

import pytest
from django.test import Client
from django.utils import timezone

from jobs import analysing, analysis_task
from jobs.analysis.thumbnails import png_encode
from jobs.eta import estimate
from jobs.models import PROGRESS_AGE_LIMIT, FileAnalysis, Job
from jobs.services import enqueue_job
from printers.models import Printer
from tests.api.printer_api_helpers import call

PRUSA = (
    Path(__file__).resolve().parent.parent
    / "data"
    / "prusaslicer-2.5_box-and-cylinder.gcode"
)


@pytest.fixture
def analysed(printer: Printer, tmp_path: Path) -> Job:
    picture = base64.b64encode(png_encode(32, 24, bytes(4 * 32 * 24))).decode()
    source = tmp_path / "box.gcode"
    source.write_text(
        f"; thumbnail begin 32x24 {len(picture)}\n; {picture}\n; thumbnail end\n"
        + PRUSA.read_text()
    )
    job = enqueue_job(printer, source, name="box.gcode")
    assert analysis_task.run(job.analysis_id) == "done"
    return Job.objects.get(pk=job.pk)


def test_the_analysis_shows_its_figures_and_layers(keys, analysed: Job) -> None:
    status, body = call("get", f"/printer/analysis/mk3/{analysed.pk}", keys("viewer"))
    assert status == 200
    data = body["data"]
    assert data["state"] == "done"
    assert data["layers"] == 50
    assert data["layer_height"] == 0.2
    assert data["slicer"] == "PrusaSlicer"
    assert data["slicer_estimated_seconds"] == 903
    assert data["objects"] == ["box.stl", "cylinder.stl"]
    assert 900 < data["estimated_seconds"] < 1100
    assert len(data["layer_list"]) == 50
    assert data["layer_list"][1]["z"] == 0.4
    assert data["thumbnails"] == [
        {"name": "32x24.png", "width": 32, "height": 24, "format": "png",
         "size": data["thumbnails"][0]["size"],
         "url": f"/printer/thumbnail/mk3/{analysed.pk}/32x24.png"},
    ]  # fmt: skip


def test_every_job_answer_carries_its_analysis(keys, analysed: Job) -> None:
    status, body = call("get", "/printer/state/mk3", keys("viewer"))
    assert status == 200
    queued = body["data"]["queue"][0]
    assert queued["analysis"]["state"] == "done"
    assert queued["analysis"]["filament_total"] > 1000
    assert queued["eta"] is None


def test_a_thumbnail_is_served_with_caching_headers(keys, analysed: Job) -> None:
    path = f"/printer/thumbnail/mk3/{analysed.pk}/32x24.png"
    key = keys("viewer")
    answer = Client().get(path, HTTP_X_API_KEY=key)
    assert answer.status_code == 200
    assert answer["Content-Type"] == "image/png"
    assert answer["Cache-Control"] == "private, max-age=86400"
    assert b"".join(answer.streaming_content).startswith(b"\x89PNG")
    again = Client().get(path, HTTP_X_API_KEY=key, HTTP_IF_NONE_MATCH=answer["ETag"])
    assert again.status_code == 304


@pytest.mark.parametrize(
    "name", ["32x24.jpg", "../32x24.png", "99x99.png", "32x24.png.exe", "x.png"]
)
def test_only_the_files_own_thumbnails_are_served(
    keys, analysed: Job, name: str
) -> None:
    path = f"/printer/thumbnail/mk3/{analysed.pk}/{name}"
    assert Client().get(path, HTTP_X_API_KEY=keys("viewer")).status_code == 404


def test_another_printers_job_is_not_found(keys, analysed: Job, make_printer) -> None:
    make_printer(slug="other")
    status, _ = call("get", f"/printer/analysis/other/{analysed.pk}", keys("viewer"))
    assert status == 404


def test_a_running_job_reports_its_eta_by_the_analysis(keys, analysed: Job) -> None:
    started = timezone.now() - timedelta(seconds=400)
    line = analysed.line_count // 2
    Job.objects.filter(pk=analysed.pk).update(
        state=Job.State.PRINTING, started_at=started, lines_acked=line,
        bytes_acked=analysed.size_bytes // 2,
    )  # fmt: skip
    status, body = call("get", "/printer/state/mk3", keys("viewer"))
    job = body["data"]["job"]
    assert job["eta_origin"] == "mixed-analysis"
    assert 1 <= job["layer"] <= job["layers"] == 50
    assert 0 < job["time_progress"] < 100
    assert job["filament_used"] > 0
    assert job["ends_at"] is not None
    # Not the linear guess (400 s more): the analysis's estimate at that line.
    said = estimate(analysing.analysis_of(analysed), line=line, elapsed=400)
    assert job["eta"] == pytest.approx(said.remaining, abs=2)


def test_the_eta_is_reckoned_when_the_progress_was_saved_and_brought_to_now(
    keys, analysed: Job
) -> None:
    now = timezone.now()
    line = analysed.line_count // 2
    Job.objects.filter(pk=analysed.pk).update(
        state=Job.State.PRINTING, started_at=now - timedelta(seconds=400),
        lines_acked=line, bytes_acked=analysed.size_bytes // 2,
        progress_at=now - timedelta(seconds=4),
    )  # fmt: skip
    _, body = call("get", "/printer/state/mk3", keys("viewer"))
    # The line was acknowledged 396 s in; 4 s of the rest have run since.
    said = estimate(analysing.analysis_of(analysed), line=line, elapsed=396)
    assert body["data"]["job"]["eta"] == pytest.approx(said.remaining - 4, abs=1)


def test_a_paused_job_keeps_its_eta_while_it_waits(keys, analysed: Job) -> None:
    now = timezone.now()
    line = analysed.line_count // 2
    Job.objects.filter(pk=analysed.pk).update(
        state=Job.State.PAUSED, started_at=now - timedelta(seconds=400),
        lines_acked=line, bytes_acked=analysed.size_bytes // 2,
        progress_at=now - timedelta(seconds=60),
    )  # fmt: skip
    _, body = call("get", "/printer/state/mk3", keys("viewer"))
    said = estimate(analysing.analysis_of(analysed), line=line, elapsed=400)
    assert body["data"]["job"]["eta"] == pytest.approx(said.remaining, abs=2)


def test_the_linear_guess_is_also_brought_to_now(keys, printer, make_job) -> None:
    now = timezone.now()
    job = make_job(printer, "G1 X1\n" * 100)
    Job.objects.filter(pk=job.pk).update(
        state=Job.State.PRINTING, started_at=now - timedelta(seconds=100),
        bytes_acked=job.size_bytes // 4, progress_at=now - timedelta(seconds=4),
    )  # fmt: skip
    job.refresh_from_db()
    # A quarter done 96 s in: 288 s left then, 284 s now (not 300 s).
    assert job.timing()["eta"] == pytest.approx(284, abs=1)
    assert job.timing()["eta_origin"] == "linear"


def test_a_progress_long_unsaved_moves_the_eta_on_by_the_limit_only(
    keys, printer, make_job
) -> None:
    """A worker that cannot write for a minute, or a worker host whose clock is a
    minute behind, moves the estimate by PROGRESS_AGE_LIMIT, not by the minute."""
    now = timezone.now()
    job = make_job(printer, "G1 X1\n" * 100)
    saved = now - timedelta(seconds=60)
    Job.objects.filter(pk=job.pk).update(
        state=Job.State.PRINTING, started_at=saved - timedelta(seconds=100),
        bytes_acked=job.size_bytes // 4, progress_at=saved,
    )  # fmt: skip
    job.refresh_from_db()
    # A quarter done 100 s in: 300 s left then.
    assert job.timing()["eta"] == pytest.approx(300 - PROGRESS_AGE_LIMIT, abs=1)


def test_analyse_again_resets_a_failed_analysis(keys, analysed: Job) -> None:
    FileAnalysis.objects.filter(pk=analysed.analysis_id).update(
        state=FileAnalysis.State.FAILED, reason="disk error"
    )
    status, body = call(
        "post", f"/printer/analysis/mk3/{analysed.pk}/again", keys("operator")
    )
    assert status == 200
    row = FileAnalysis.objects.get(pk=analysed.analysis_id)
    assert (row.state, row.reason) == ("pending", "")
    FileAnalysis.objects.filter(pk=row.pk).update(state=FileAnalysis.State.RUNNING)
    status, body = call(
        "post", f"/printer/analysis/mk3/{analysed.pk}/again", keys("operator")
    )
    assert status == 409
    assert "running" in body["error"]


def test_octoprint_files_carry_gcode_analysis_and_a_thumbnail(
    keys, analysed: Job
) -> None:
    key = keys("viewer")
    status, body = call("get", "/p/mk3/api/files", key)
    assert status == 200
    info = body["files"][0]
    analysis = info["gcodeAnalysis"]
    assert 900 < analysis["estimatedPrintTime"] < 1100
    assert analysis["filament"]["tool0"]["length"] == pytest.approx(1025, abs=5)
    assert analysis["filament"]["tool0"]["volume"] == pytest.approx(2.47, abs=0.05)
    assert analysis["dimensions"]["height"] == pytest.approx(9.8)
    # The thumbnail is relative to the API's base, as OctoPrint apps expect.
    answer = Client().get(f"/p/mk3/{info['thumbnail']}", HTTP_X_API_KEY=key)
    assert answer.status_code == 200
    assert answer["Content-Type"] == "image/png"
    status, one = call("get", f"/p/mk3/api/files/local/{info['name']}", key)
    assert one["gcodeAnalysis"] == analysis


def test_octoprint_job_reports_estimate_filament_and_time_left(
    keys, analysed: Job
) -> None:
    Job.objects.filter(pk=analysed.pk).update(
        state=Job.State.PRINTING, started_at=timezone.now() - timedelta(seconds=300),
        lines_acked=analysed.line_count // 3, bytes_acked=analysed.size_bytes // 3,
    )  # fmt: skip
    status, body = call("get", "/p/mk3/api/job", keys("viewer"))
    assert status == 200
    assert 900 < body["job"]["estimatedPrintTime"] < 1100
    assert body["job"]["filament"]["tool0"]["length"] > 1000
    assert body["progress"]["printTimeLeftOrigin"] == "mixed-analysis"
    assert 0 < body["progress"]["printTimeLeft"] < 1100


def test_moonraker_metadata_and_its_thumbnail_path(keys, analysed: Job) -> None:
    key = keys("viewer")
    name = analysed.file.rsplit("/", 1)[-1]
    status, body = call("get", f"/p/mk3/server/files/metadata?filename={name}", key)
    assert status == 200
    meta = body["result"]
    assert meta["slicer"] == "PrusaSlicer"
    assert meta["layer_height"] == 0.2
    assert meta["object_height"] == 10.0
    assert meta["layer_count"] == 50
    assert meta["filament_total"] > 1000
    assert 900 < meta["estimated_time"] < 1100
    (picture,) = meta["thumbnails"]
    assert (picture["width"], picture["height"]) == (32, 24)
    path = f"/p/mk3/server/files/gcodes/{picture['relative_path']}"
    assert Client().get(path, HTTP_X_API_KEY=key).status_code == 200
    status, body = call("get", "/p/mk3/server/files/metadata?filename=nope.gcode", key)
    assert status == 404
    assert body["error"]["message"] == "Metadata not available for <nope.gcode>"
