"""POST /printer/objects/<slug>: validation, intent written, nothing changed on refusal."""

from __future__ import annotations

import json

import pytest
from django.test import Client

from jobs import analysis_task
from jobs.models import Job
from jobs.services import enqueue_job
from printers.models import QueuedCommand

LABELLED = (
    "G28\n; printing object a id:0 copy 0\nG1 X5 E1\n; stop printing object a\n"
    "; printing object b id:1 copy 0\nG1 X9 E2\n; stop printing object b\n"
    "; printing object c id:2 copy 0\nG1 X12 E3\n; stop printing object c\n"
)


@pytest.fixture
def client(django_user_model) -> Client:
    client = Client()
    client.force_login(django_user_model.objects.create_superuser("op", "", "op"))
    return client


def make_job(make_printer, tmp_path, text: str = LABELLED, state: str = "printing"):
    printer = make_printer(slug="p")
    source = tmp_path / "parts.gcode"
    source.write_text(text)
    job = enqueue_job(printer, source, name="parts.gcode")
    analysis_task.run(job.analysis_id)
    Job.objects.filter(pk=job.pk).update(state=state)
    return Job.objects.get(pk=job.pk)


def post(client: Client, job_id: object, name: object):
    answer = client.post(
        "/printer/objects/p",
        data=json.dumps({"id": job_id, "object": name}),
        content_type="application/json",
    )
    return answer.status_code, answer.json()


def test_it_writes_the_intent_and_asks_the_worker(client, make_printer, tmp_path):
    job = make_job(make_printer, tmp_path)
    status, body = post(client, job.pk, "b")
    assert status == 202
    assert body["data"]["cancelled"] == ["b"]
    assert Job.objects.get(pk=job.pk).cancelled_objects == ["b"]
    row = QueuedCommand.objects.get()
    assert (row.kind, row.text) == ("action", f"cancel_object:{job.pk}")
    objects = client.get(f"/printer/objects/p?id={job.pk}").json()["data"]
    assert objects["objects"] == ["a", "b", "c"]
    assert objects["cancelled"] == ["b"]


@pytest.mark.parametrize(
    ("state", "name", "before", "status", "says"),
    [
        ("printing", "nope", [], 404, "no object 'nope'"),
        ("completed", "b", [], 409, "not printing"),
        ("queued", "b", [], 409, "not printing"),
        ("printing", "b", ["b"], 409, "already cancelled"),
        ("printing", "c", ["a", "b"], 409, "last object"),
        ("printing", "", [], 422, "send"),
    ],
)
def test_it_refuses_and_changes_nothing(
    client, make_printer, tmp_path, state, name, before, status, says
):
    job = make_job(make_printer, tmp_path, state=state)
    Job.objects.filter(pk=job.pk).update(cancelled_objects=before)
    got, body = post(client, job.pk, name)
    assert got == status
    assert says in body["error"]
    assert Job.objects.get(pk=job.pk).cancelled_objects == before
    assert not QueuedCommand.objects.exists()


def test_a_file_without_objects_is_refused(client, make_printer, tmp_path):
    job = make_job(make_printer, tmp_path, text="G28\nG1 X5 E1\n")
    status, body = post(client, job.pk, "a")
    assert status == 409
    assert "names no objects" in body["error"]
    assert not QueuedCommand.objects.exists()


def test_an_unknown_job_is_404(client, make_printer, tmp_path):
    make_job(make_printer, tmp_path)
    assert post(client, 999, "a")[0] == 404


def test_object_ranges_are_read_from_the_file_once_by_the_analysis(
    client, make_printer, tmp_path, monkeypatch
):
    """Reading a large file for them takes seconds: every viewer of the job's page
    (or one asking again and again) would pay them."""
    from printers.streaming import object_places

    job = make_job(make_printer, tmp_path)
    monkeypatch.setattr(object_places, "ObjectFilter", None)  # no second read
    answer = client.get(f"/printer/objects/p?id={job.pk}&ranges=1")

    assert answer.status_code == 200
    assert answer.json()["data"]["ranges"] == {
        "a": [[1, 2]], "b": [[2, 3]], "c": [[3, 4]],
    }  # fmt: skip
