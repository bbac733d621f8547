"""A cancelled object stays cancelled in a run resumed mid-file (rule O10 in
printers/streaming/objects.py), whether the file marks its objects with comments or
names them once with `M486 A` and starts each part with `M486 S<n>` alone."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import pytest

from jobs import analysis_task
from jobs.models import Job
from jobs.resume.planning import make_plan, request_plan, start_plan
from jobs.services import enqueue_job
from printers.streaming import Line
from printers.streaming.object_places import place_at
from printers.streaming.objects import ObjectFilter
from printers.worker.spool import stream_for
from tests.objects.gcode_model import Machine, entries_of, m486_labels

THREE = Path(__file__).parents[1] / "data" / "prusaslicer-2.5_three-boxes.gcode"
B = "box-b.stl"
LABELS = {"comments": lambda text: text, "m486": m486_labels}


class Slice:
    """The three boxes read whole: each command's object and the ones that draw."""

    def __init__(self, text: str) -> None:
        self.entries = entries_of(text)
        self.texts = {e.index: e.text for e in self.entries if isinstance(e, Line)}
        whole = ObjectFilter(self.entries)
        self.owner = {line.index: whole.active for line in whole}
        self.m486_ids = whole.m486_ids
        machine, self.draws = Machine(), set()
        for index, command in self.texts.items():
            before = len(machine.segments)
            machine.run(command)
            if len(machine.segments) > before:
                self.draws.add(index)

    def inside_b_again(self) -> int:
        """A command that draws a few lines into box B's second part that draws
        (its second layer)."""
        b_lines = sorted(i for i, name in self.owner.items() if name == B)
        parts: list[list[int]] = [[b_lines[0]]]
        for before, index in itertools.pairwise(b_lines):
            if index == before + 1:
                parts[-1].append(index)
            else:
                parts.append([index])
        drawing = [[i for i in part if i in self.draws] for part in parts]
        return [part for part in drawing if part][1][4]

    def after(self, start: int) -> list:
        """The entries a run resumed at *start* reads (from command start-1's end)."""
        cut = next(k for k, e in enumerate(self.entries) if getattr(e, "index", -2)
                   == start - 1)  # fmt: skip
        return self.entries[cut + 1 :]

    def check(self, sent: list[Line], start: int) -> None:
        """No line of B's that draws went; every other object's did, as in the file."""
        as_filed = {line.index for line in sent if line.text == self.texts[line.index]}
        later = {i for i in self.draws if i >= start}
        b_draws = {i for i in later if self.owner[i] == B}
        assert b_draws, "box B draws after the start line"
        assert not b_draws & as_filed, "box B drew again in the resumed run"
        others = {i for i in later if self.owner[i] not in (B, None)}
        assert others <= as_filed, "another object lost lines in the resumed run"


@pytest.mark.parametrize("labels", sorted(LABELS))
def test_a_run_resumed_inside_a_cancelled_object_never_draws_it(labels):
    file = Slice(LABELS[labels](THREE.read_text()))
    start = file.inside_b_again()
    # Kept as JSON with the job, as the database stores it.
    place = json.loads(json.dumps(place_at(file.entries, start)))
    assert place["active"] == B

    resumed = ObjectFilter(file.after(start), cancelled={B}, place=place)
    file.check(list(resumed), start)
    assert resumed.m486_ids == file.m486_ids


def test_a_place_before_any_object_is_the_empty_one():
    file = Slice(m486_labels(THREE.read_text()))
    assert place_at(file.entries, 0) == ObjectFilter([]).place()
    assert place_at(file.entries, 3)["active"] is None


def test_a_resume_plan_gives_its_run_the_object_streaming_at_its_line(
    make_printer, tmp_path
):
    source = tmp_path / "three.gcode"
    source.write_text(m486_labels(THREE.read_text()))
    file = Slice(source.read_text())
    start = file.inside_b_again()
    job = enqueue_job(make_printer(), source, name=source.name)
    analysis_task.run(job.analysis_id)  # what the Celery worker does
    Job.objects.filter(pk=job.pk).update(
        state=Job.State.INTERRUPTED, cancelled_objects=[B], lines_acked=start
    )

    plan = request_plan(Job.objects.get(pk=job.pk), line=start)
    assert make_plan(plan.pk) == "ready"  # what the Celery worker does
    plan.refresh_from_db()
    resumed = start_plan(plan)

    assert Job.objects.get(pk=resumed.pk).start_objects["active"] == B
    stream = stream_for(Job.objects.get(pk=resumed.pk))
    sent = [line for line in stream.lines if line.index >= start]
    file.check(sent, start)
