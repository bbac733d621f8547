"""Cancel one object of a real three-object slice mid-print, over a real pty.

A worker prints PrusaSlicer's three boxes on the Marlin simulator; once box B's
second layer streams, an operator cancels box B through the API. The firmware's
record then holds every line of boxes A and C, none of B's extrusion after the
cancel, and E where the file has it. With `--cancel-objects` (M486) the worker
sends `M486 P1` instead and every line of the file reaches the firmware, which
skips box B's moves itself.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from django.test import Client

from jobs import analysis_task
from jobs.models import Job
from jobs.services import enqueue_job
from printers.models import ResponseLine
from printers.streaming import Line
from printers.worker.loop import PrinterWorker
from tests.conftest import job_lines, wait_for
from tests.objects.gcode_model import (
    Machine,
    Segment,
    entries_of,
    file_segments,
    m486_labels,
)
from tests.printers.stream_checks import sim_stats

pytestmark = pytest.mark.slow

THREE = Path(__file__).parents[1] / "data" / "prusaslicer-2.5_three-boxes.gcode"
B = "box-b.stl"
#: What the filter adds (printers/streaming/objects.py rules O3, O5-O7).
ADDED = re.compile(r"^(G92 E[-\d.]+|G1 F[\d.]+|G0 X[-\d.]+ Y[-\d.]+|G1 Z[-\d.]+)$")


def start(make_printer, sim, source: Path) -> tuple[PrinterWorker, Job]:
    printer = make_printer(port=str(sim.link), baud=250000)
    job = enqueue_job(printer, source, name=source.name)
    analysis_task.run(job.analysis_id)  # what the Celery worker does
    job = Job.objects.get(pk=job.pk)
    assert job.objects_list() == ["box-a.stl", "box-b.stl", "box-c.stl"]
    worker = PrinterWorker(printer)
    worker.start()
    return worker, job


def cancel_in_second_layer(worker, job, second: int, client) -> None:
    """Tick until box B's second layer (from line *second*) streams, then cancel B
    through the API."""
    acked = lambda: Job.objects.get(pk=job.pk).lines_acked
    wait_for(lambda: acked() >= second + 5, 60, "box B's 2nd layer", worker.tick)
    answer = client.post(
        f"/printer/objects/{job.printer.slug}",
        data=json.dumps({"id": job.pk, "object": B}),
        content_type="application/json",
    )
    assert answer.status_code == 202, answer.content
    assert answer.json()["data"]["cancelled"] == [B]


def finish(worker, job, sim, *, then: str = "") -> list[str]:
    """Tick until the job completes (then send *then* and wait for its reply in the
    response log), stop the worker; the job's lines the firmware ran."""
    try:
        wait_for(
            lambda: Job.objects.get(pk=job.pk).state == "completed", 120,
            "the job to complete", worker.tick,
        )  # fmt: skip
        if then:
            worker.submit_internal(then)
            wait_for(
                lambda: ResponseLine.objects.filter(text__contains="Canceled").exists(),
                30, f"the firmware's answer to {then}", worker.tick,
            )  # fmt: skip
    finally:
        worker.stop()
    wait_for(lambda: len(sim.executed()) >= sim_stats(sim)["executed"], 5, "record")
    return job_lines(sim)


def check_b_stops_and_the_rest_is_whole(whole: Machine, printed: Machine) -> None:
    """Printed segments are the file's minus a tail of box B's (none after the
    cancel), with B cut mid-print, and the E each pushed is the file's."""
    key = lambda s: (s.start, s.end, s.e, s.z)
    mine = [key(s) for s in printed.segments]
    kept = [s for s in whole.segments if key(s) in set(mine)]
    assert [key(s) for s in kept] == mine, "extrusion out of order or not the file's"
    missing: list[Segment] = [s for s in whole.segments if key(s) not in set(mine)]
    assert missing, "box B was not cancelled"
    assert {s.object for s in missing} == {B}, "only box B may lose extrusion"
    b_segments = [key(s) for s in whole.segments if s.object == B]
    first_missing = b_segments.index(key(missing[0]))
    assert first_missing > len(b_segments) // 5, "box B was cancelled mid-print"
    assert b_segments[first_missing:] == [key(s) for s in missing], (
        "box B extruded after the cancel"
    )
    extruded = round(sum(s.e for s in printed.segments), 4)
    assert extruded == round(
        sum(s.e for s in whole.segments) - sum(s.e for s in missing), 4
    )


@pytest.fixture
def operator_client(django_user_model) -> Client:
    client = Client()
    client.force_login(django_user_model.objects.create_superuser("op", "", "op"))
    return client


def test_cancelled_object_is_skipped_host_side_and_e_stays_consistent(
    make_printer, sim_factory, operator_client
):
    sim = sim_factory("marlin", "--time-scale", "0", "--baud", "250000")
    worker, job = start(make_printer, sim, THREE)
    entries = entries_of(THREE.read_text())
    starts = [i for i, e in enumerate(entries) if getattr(e, "name", None) == B]
    second = next(e.index for e in entries[starts[1] :] if isinstance(e, Line))
    cancel_in_second_layer(worker, job, second, operator_client)
    ran = finish(worker, job, sim)

    whole, printed = file_segments(entries), Machine()
    for command in ran:
        printed.run(command)
    check_b_stops_and_the_rest_is_whole(whole, printed)
    # Retracts and unretracts balance as in the file; E and Z end on the file's.
    assert round(printed.other_e, 4) == round(whole.other_e, 4)
    assert round(printed.pos["E"], 4) == round(whole.pos["E"], 4)
    assert printed.pos["Z"] == whole.pos["Z"]
    # Every line but B's dropped extrusion ran, in order (A and C whole, the
    # slicer's travels and Z hops); what else ran is what the filter adds.
    # (B's extrusion before the cancel ran too: the segments above say where.)
    b_lines = _extrusions_of(entries, B)
    dropped, b_texts = {id(e) for e in b_lines}, {e.text for e in b_lines}
    expected = [e.text for e in entries if isinstance(e, Line) and id(e) not in dropped]
    left = iter(ran)
    for text in expected:
        for command in left:
            if command == text:
                break
            assert command in b_texts or ADDED.match(command), (
                f"{command!r} is neither the file's nor added"
            )
        else:
            pytest.fail(f"{text!r} never ran")
    assert "M486 P1" not in ran
    job.refresh_from_db()
    assert job.as_dict()["objects"][1] == {"name": B, "cancelled": True}


def test_m486_firmware_is_sent_m486_p_and_skips_the_object_itself(
    make_printer, sim_factory, operator_client, tmp_path
):
    source = tmp_path / "three-boxes-m486.gcode"
    source.write_text(m486_labels(THREE.read_text()))
    sim = sim_factory(
        "marlin", "--time-scale", "0", "--baud", "250000", "--cancel-objects"
    )
    worker, job = start(make_printer, sim, source)
    entries = entries_of(THREE.read_text())
    labelled = entries_of(source.read_text())
    b_starts = [e.index for e in labelled if getattr(e, "text", "") == "M486 S1"]
    cancel_in_second_layer(worker, job, b_starts[2], operator_client)
    ran = finish(worker, job, sim, then="M486")

    assert ran.count("M486 P1") == 1
    # The host skipped nothing: the file's lines all ran, M486 P1 among them.
    without = [c for c in ran if c != "M486 P1"]
    assert without[:-1] == [e.text for e in labelled if isinstance(e, Line)]
    whole, printed = file_segments(entries), Machine()
    for command in ran:
        printed.run(command)  # the model skips as the firmware does (M486)
    check_b_stops_and_the_rest_is_whole(whole, printed)
    assert round(printed.pos["E"], 4) == round(whole.pos["E"], 4)
    # The firmware says so itself.
    report = ResponseLine.objects.filter(text__contains="Canceled").first()
    assert report.text.endswith("Canceled: 1")


def _extrusions_of(entries, name: str) -> list[Line]:
    """The lines of object *name* that extrude (what the host may drop)."""
    machine, out = Machine(), []
    for entry in entries:
        if not isinstance(entry, Line):
            machine.active = entry.name
            continue
        before = len(machine.segments)
        machine.run(entry.text)
        if len(machine.segments) > before and machine.active == name:
            out.append(entry)
    return out
