"""The preview's geometry: polylines per layer, thinned within a bound, served a layer
at a time."""

from __future__ import annotations

import io
import itertools
import math
from typing import TYPE_CHECKING

import numpy as np
import pytest
from django.test import Client

from jobs import analysis_task
from jobs.analysis.analyser import Analyser
from jobs.analysis.toolpath import TOLERANCE
from jobs.services import enqueue_job
from printhost.access import issue_key
from tests.slices import CURA, PRUSA

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from printers.models import Printer


def records(data: bytes) -> list[dict]:
    """The records of toolpath bytes, as the browser reads them."""
    words = np.frombuffer(data, np.uint32)
    floats = np.frombuffer(data, np.float32)
    out, at = [], 0
    while at < len(words):
        count = int(words[at + 2])
        key = int(words[at + 1])
        points = floats[at + 3 : at + 3 + 2 * count].reshape(-1, 2)
        out.append(
            {
                "command": int(words[at]),
                "drawn": key & 0xFF == 1,
                "feature": (key >> 8) & 0xFF,
                "speed": key >> 16,
                "points": points.astype(float).tolist(),
            }
        )
        at += 3 + 2 * count
    assert at == len(words)
    return out


def analyse(text: bytes | str) -> tuple[object, bytes]:
    sink = io.BytesIO()
    analyser = Analyser(toolpath=sink)
    analyser.feed(text.encode() if isinstance(text, str) else text)
    return analyser.finish(), sink.getvalue()


def layer_records(result, data: bytes, number: int) -> list[dict]:
    start, end = result.toolpath["layers"][number]
    return records(data[start:end])


def test_every_layer_of_a_real_slice_has_its_moves_and_nothing_else() -> None:
    result, data = analyse(PRUSA.read_bytes())
    bounds = result.toolpath["layers"]
    assert len(bounds) == len(result.layers) == 50
    # Consecutive, in order, covering the file's records from the first layer on.
    assert all(a[1] == b[0] for a, b in itertools.pairwise(bounds))
    assert bounds[-1][1] == len(data)
    for number, layer in enumerate(result.layers):
        found = layer_records(result, data, number)
        assert found, number
        following = result.layers[number + 1].line if number + 1 < 50 else math.inf
        assert all(layer.line <= r["command"] < following for r in found), number
    features = result.toolpath["features"]
    assert {"Perimeter", "External perimeter", "Solid infill"} <= set(features)
    first = layer_records(result, data, 0)
    drawn = [r for r in first if r["drawn"]]
    assert {features[r["feature"]] for r in drawn} >= {"Skirt/Brim", "Perimeter"}
    assert any(not r["drawn"] for r in first)  # travel moves are kept too


def test_drawn_points_stay_inside_the_parts_box() -> None:
    for path in (PRUSA, CURA):
        result, data = analyse(path.read_bytes())
        (x0, y0, _), (x1, y1, _) = result.bbox
        points = np.array([p for r in records(data) if r["drawn"] for p in r["points"]])
        assert points[:, 0].min() >= x0 - 1e-3 and points[:, 0].max() <= x1 + 1e-3
        assert points[:, 1].min() >= y0 - 1e-3 and points[:, 1].max() <= y1 + 1e-3


def test_a_straight_line_in_pieces_is_one_segment_and_a_circle_keeps_its_shape() -> (
    None
):
    pieces = "".join(f"G1 X{x / 10:.1f} E{x / 100:.2f}\n" for x in range(1, 101))
    circle = "".join(
        f"G1 X{50 + 20 * math.cos(a / 90 * math.pi):.3f}"
        f" Y{50 + 20 * math.sin(a / 90 * math.pi):.3f} E{1 + a / 100:.2f}\n"
        for a in range(181)
    )
    result, data = analyse("G28\nG1 Z0.2 F1200\n" + pieces + "G1 X70 Y50\n" + circle)
    drawn = [r for r in records(data) if r["drawn"]]
    line, ring = drawn[0]["points"], drawn[1]["points"]
    assert line[0] == [0.0, 0.0] and line[-1] == pytest.approx([10.0, 0.0])
    assert len(line) < 20  # of 101
    assert 20 < len(ring) <= 182
    # Every point of the circle is within the tolerance of the drawn polygon.
    polygon = np.array(ring)
    for a in range(181):
        x = 50 + 20 * math.cos(a / 90 * math.pi)
        y = 50 + 20 * math.sin(a / 90 * math.pi)
        distances = [
            _distance((x, y), polygon[i], polygon[i + 1])
            for i in range(len(polygon) - 1)
        ]
        assert min(distances) <= TOLERANCE + 1e-4


def _distance(p, a, b) -> float:
    a, b, p = np.asarray(a), np.asarray(b), np.asarray(p)
    ab = b - a
    share = np.clip(np.dot(p - a, ab) / max(np.dot(ab, ab), 1e-12), 0, 1)
    return float(np.linalg.norm(a + share * ab - p))


def test_a_turn_back_is_never_thinned_away() -> None:
    zigzag = "G1 X10 E1\nG1 X0 E2\nG1 X10 E3\nG1 X0 E4\n"
    _, data = analyse("G28\nG1 Z0.2\n" + zigzag)
    drawn = [r for r in records(data) if r["drawn"]]
    assert [p[0] for p in drawn[0]["points"]] == [0, 10, 0, 10, 0]


def test_speed_and_feature_changes_start_new_polylines() -> None:
    text = (
        "G28\nG1 Z0.2\n;TYPE:Perimeter\nG1 X10 E1 F1200\nG1 X20 E2\n"
        "G1 X30 E3 F3000\n;TYPE:Internal infill\nG1 X40 E4\nG0 X0 Y5\n"
    )
    result, data = analyse(text)
    drawn = [(r["feature"], r["speed"], len(r["points"])) for r in records(data)]
    features = result.toolpath["features"]
    named = [(features[f], s, n) for f, s, n in drawn]
    assert named[-4:] == [
        ("Perimeter", 20, 2),  # X0 -> X20 at 20 mm/s, thinned to its ends
        ("Perimeter", 50, 2),
        ("Internal infill", 50, 2),
        ("Internal infill", 50, 2),  # the travel (not drawn), same feature
    ]
    assert [r["drawn"] for r in records(data)][-1] is False


@pytest.fixture
def analysed(
    make_printer: Callable[..., Printer], monkeypatch: pytest.MonkeyPatch
) -> tuple[Printer, object, Client]:
    monkeypatch.setattr("jobs.tasks.analyse_file.delay", lambda pk: None)
    printer = make_printer(slug="mk4")
    job = enqueue_job(printer, PRUSA, name="box.gcode", origin="test", queue=False)
    assert analysis_task.run(job.analysis_id) == "done"
    from django.contrib.auth import get_user_model

    from printhost.models import PrinterRole, Role

    user = get_user_model().objects.create_user("viewer", password="x" * 12)
    PrinterRole.objects.create(user=user, printer=printer, role=Role.VIEWER)
    client = Client(headers={"X-Api-Key": issue_key(user, "t")[1]})
    return printer, job, client


def test_the_api_serves_one_layer_at_a_time_with_caching(
    analysed, tmp_path: Path
) -> None:
    _, job, client = analysed
    info = client.get(f"/printer/analysis/mk4/{job.pk}").json()["data"]
    assert info["toolpath"]["url"] == f"/printer/toolpath/mk4/{job.pk}/"
    assert len(info["toolpath"]["bytes"]) == len(info["layer_list"]) == 50
    response = client.get(f"/printer/toolpath/mk4/{job.pk}/3")
    assert response.status_code == 200
    assert response["Content-Type"] == "application/octet-stream"
    assert len(response.content) == info["toolpath"]["bytes"][3]
    layer = info["layer_list"][3]
    assert all(r["command"] >= layer["line"] for r in records(response.content))
    again = client.get(
        f"/printer/toolpath/mk4/{job.pk}/3", headers={"If-None-Match": response["ETag"]}
    )
    assert again.status_code == 304
    assert client.get(f"/printer/toolpath/mk4/{job.pk}/50").status_code == 404
    assert (
        "layers 0 to 49"
        in client.get(f"/printer/toolpath/mk4/{job.pk}/99").json()["error"]
    )


def test_a_file_without_layers_has_no_toolpath_to_serve(
    analysed, make_printer: Callable[..., Printer], tmp_path: Path
) -> None:
    printer, _, client = analysed
    source = tmp_path / "home.gcode"
    source.write_text("G28\nM84\n")
    job = enqueue_job(printer, source, name="home.gcode", origin="test", queue=False)
    assert analysis_task.run(job.analysis_id) == "done"
    response = client.get(f"/printer/toolpath/mk4/{job.pk}/0")
    assert response.status_code == 404
    assert "no toolpath" in response.json()["error"]


def test_a_cnc_job_is_drawn_whole_as_one_layer() -> None:
    sink = io.BytesIO()
    analyser = Analyser(firmware="grbl", toolpath=sink)
    analyser.feed(
        b"G21 G90\nG0 Z5\nG0 X0 Y0\nG1 Z-1 F300\nG1 X20 F600\nG2 X40 Y0 I10 J0\n"
        b"G1 Y-10\nG0 Z5\nG0 X0 Y0\n"
    )
    result = analyser.finish()
    assert result.layers == []
    assert result.toolpath["layers"] == [[0, len(sink.getvalue())]]
    found = records(sink.getvalue())
    cuts = [r for r in found if r["drawn"]]
    assert {r["speed"] for r in cuts} == {5, 10}  # the plunge at F300, cuts at F600
    arc = max(cuts, key=lambda r: len(r["points"]))["points"]
    assert max(y for _, y in arc) == pytest.approx(10, abs=0.05)  # the arc's top
    assert any(not r["drawn"] for r in found)  # the rapids


def test_a_cnc_jobs_preview_is_one_layer_in_the_api(
    analysed, make_printer: Callable[..., Printer], tmp_path: Path
) -> None:
    _, _, client = analysed
    from printers.models import Printer as PrinterModel
    from printhost.models import PrinterRole, Role

    router = make_printer(slug="cnc", firmware="grbl")
    user = PrinterRole.objects.get(role=Role.VIEWER).user
    PrinterRole.objects.create(user=user, printer=router, role=Role.VIEWER)
    source = tmp_path / "pocket.nc"
    source.write_text("G21 G90\nG0 Z5\nG1 Z-1 F300\nG1 X20 Y5 F600\nG0 Z5\n")
    job = enqueue_job(router, source, name="pocket.nc", origin="test", queue=False)
    assert analysis_task.run(job.analysis_id) == "done"
    info = client.get(f"/printer/analysis/cnc/{job.pk}").json()["data"]
    # The plunge from Z5 cuts: the job's top is 5 mm.
    assert info["layer_list"] == [{"z": 5.0, "line": 0, "time": 0.0}]
    assert PrinterModel.objects.get(slug="cnc").is_grbl
    assert len(info["toolpath"]["bytes"]) == 1
    layer = client.get(f"/printer/toolpath/cnc/{job.pk}/0")
    assert layer.status_code == 200
    assert any(r["drawn"] for r in records(layer.content))


def test_the_toolpath_stops_at_its_cap_and_says_so(monkeypatch) -> None:
    """A small compressed file can unpack to gigabytes of moves: the preview's file
    (and a layer a viewer reads whole) must not follow it."""
    from jobs.analysis import toolpath

    run = "".join(f"G1 X{i % 2 * 50} Y{i} E1 F{1200 + i}\n" for i in range(1000))
    text = ("G28\nM83\nG1 Z0.2\n" + run * 200).encode()

    def drawn() -> tuple[object, bytes]:
        """Fed a megabyte at a time, as the analysis task reads a file."""
        sink = io.BytesIO()
        analyser = Analyser(toolpath=sink)
        for at in range(0, len(text), 1 << 20):
            analyser.feed(text[at : at + (1 << 20)])
        return analyser.finish(), sink.getvalue()

    _, whole = drawn()
    monkeypatch.setattr(toolpath, "MAX_BYTES", 4096)
    result, data = drawn()
    # What the first megabyte drew, and nothing after it.
    assert 4096 <= len(data) <= len(whole) / 3, "drawn on past the cap"
    assert "the preview draws the first 256 MB of the toolpath only" in result.notes


def test_feature_names_past_the_cap_are_not_remembered() -> None:
    from jobs.analysis.toolpath import MAX_FEATURES, ToolpathWriter

    writer = ToolpathWriter(io.BytesIO())
    indexes = [writer.feature(f"kind {n}") for n in range(MAX_FEATURES + 50)]
    assert indexes[-51:] == [MAX_FEATURES] * 51
    assert len(writer.features) == MAX_FEATURES + 1
    assert len(writer._feature_ids) == MAX_FEATURES + 1
