"""The resume API: plan a resume, read its preamble, start it; refusals change nothing."""

from __future__ import annotations

import json

import pytest
from django.test import Client

from jobs.analysis_task import run as analyse
from jobs.models import Job, ResumePlan
from jobs.resume.planning import make_plan
from printers.models import QueuedCommand
from tests.resume.prints import layered_print

TEXT = layered_print(layers=4, per_layer=10)


def call(method: str, path: str, key: str, **data: object) -> tuple[int, dict]:
    client = Client()
    if method == "post":
        response = client.post(
            path, json.dumps(data), content_type="application/json",
            HTTP_X_API_KEY=key,
        )  # fmt: skip
    else:
        response = client.get(path, data, HTTP_X_API_KEY=key)
    return response.status_code, json.loads(response.content)


@pytest.fixture
def stopped(printer, make_job) -> Job:
    """A job analysed, then interrupted at its 30th command."""
    job = make_job(printer, TEXT)
    analyse(job.analysis_id)
    Job.objects.filter(pk=job.pk).update(state=Job.State.INTERRUPTED, lines_acked=30)
    job.refresh_from_db()
    return job


def _nothing_changed(job: Job) -> None:
    assert not ResumePlan.objects.exists()
    assert Job.objects.count() == 1
    assert Job.objects.get(pk=job.pk).state == job.state


def test_a_plan_shows_its_preamble_and_starts_the_resumed_run_first(
    keys, stopped, printer, make_job
) -> None:
    waiting = make_job(printer, TEXT)
    status, body = call("post", "/printer/resume/mk3", keys(), id=stopped.pk)
    assert status == 200, body
    plan = body["data"]
    assert (plan["state"], plan["line"], plan["preamble"]) == ("pending", 30, [])

    assert make_plan(plan["id"]) == "ready"  # what the Celery task runs
    status, body = call("get", "/printer/resume/mk3", keys("viewer"), plan=plan["id"])
    ready = body["data"]
    assert ready["state"] == "ready"
    assert "G28 X Y ; home X and Y only: the part is on the bed" in ready["preamble"]
    assert ready["machine"]["heaters"] == {"bed": 60.0, "tool0": 210.0}

    status, body = call("post", "/printer/resume/mk3/start", keys(), plan=plan["id"])
    assert status == 200, body
    resumed = Job.objects.get(pk=body["data"]["id"])
    assert resumed.resume_of_id == stopped.pk
    assert (resumed.start_line, resumed.state) == (30, Job.State.QUEUED)
    assert resumed.preamble == "\n".join(ready["preamble"])
    assert resumed.position < Job.objects.get(pk=waiting.pk).position  # first
    assert TEXT.encode()[: resumed.start_offset].count(b"\nG1 X") > 0
    assert TEXT[resumed.start_offset :].startswith(
        [c for c in TEXT.splitlines() if c and not c.startswith(";")][30]
    )
    assert QueuedCommand.objects.filter(text=QueuedCommand.Action.BED_CLEAR).exists()
    # A plan starts once.
    status, body = call("post", "/printer/resume/mk3/start", keys(), plan=plan["id"])
    assert status == 409 and "started" in body["error"]


def test_options_list_the_last_acked_line_and_the_layers(keys, stopped) -> None:
    status, body = call("get", "/printer/resume/mk3", keys("viewer"), id=stopped.pk)
    assert status == 200
    data = body["data"]
    assert data["last_line"] == 30
    assert [round(layer["z"], 2) for layer in data["layers"]] == [0.2, 0.4, 0.6, 0.8]
    times = [layer["time"] for layer in data["layers"]]
    assert times == sorted(times) and times[-1] > 0


def test_a_layer_plan_starts_at_the_layers_first_line(keys, stopped) -> None:
    status, body = call("post", "/printer/resume/mk3", keys(), id=stopped.pk, layer=2)
    assert status == 200
    commands = [c for c in TEXT.splitlines() if c and not c.startswith(";")]
    assert commands[body["data"]["line"]] == "G1 Z0.6 F600"


@pytest.mark.parametrize(
    ("choice", "status", "why"),
    [
        ({"line": 10_000}, 400, "beyond the file"),
        ({"line": -1}, 400, "must be 0 or more"),
        ({"layer": 4}, 400, "has 4 layers"),
        ({"line": 3, "layer": 1}, 400, "not both"),
        ({"line": "ten"}, 400, "must be an integer"),
    ],
)
def test_a_bad_line_or_layer_is_refused(keys, stopped, choice, status, why) -> None:
    code, body = call("post", "/printer/resume/mk3", keys(), id=stopped.pk, **choice)
    assert code == status and why in body["error"]
    _nothing_changed(stopped)


@pytest.mark.parametrize(
    ("state", "why"),
    [
        (Job.State.PRINTING, "only a run that stopped"),
        (Job.State.QUEUED, "only a run that stopped"),
        (Job.State.COMPLETED, "only an interrupted, failed or aborted"),
    ],
)
def test_a_job_that_did_not_stop_is_refused(keys, stopped, state, why) -> None:
    Job.objects.filter(pk=stopped.pk).update(state=state)
    stopped.refresh_from_db()
    code, body = call("post", "/printer/resume/mk3", keys(), id=stopped.pk)
    assert code == 409 and why in body["error"]
    _nothing_changed(stopped)


def test_a_file_without_analysis_is_refused(keys, printer, make_job) -> None:
    job = make_job(printer, TEXT)  # its analysis is still pending
    Job.objects.filter(pk=job.pk).update(state=Job.State.FAILED)
    job.refresh_from_db()
    code, body = call("post", "/printer/resume/mk3", keys(), id=job.pk)
    assert code == 409 and "not analysed yet" in body["error"]
    _nothing_changed(job)


def test_unknown_jobs_plans_and_viewers_are_refused(keys, stopped) -> None:
    assert call("post", "/printer/resume/mk3", keys(), id=999)[0] == 404
    assert call("post", "/printer/resume/mk3", keys())[0] == 400
    assert call("post", "/printer/resume/mk3", keys("viewer"), id=stopped.pk)[0] == 403
    assert call("post", "/printer/resume/mk3/start", keys(), plan=999)[0] == 404
    _nothing_changed(stopped)


def test_a_pending_plan_or_a_busy_printer_does_not_start(
    keys, stopped, printer, make_job
) -> None:
    _, body = call("post", "/printer/resume/mk3", keys(), id=stopped.pk)
    plan = body["data"]["id"]
    code, body = call("post", "/printer/resume/mk3/start", keys(), plan=plan)
    assert code == 409 and "pending" in body["error"]

    make_plan(plan)
    other = make_job(printer, TEXT)
    Job.objects.filter(pk=other.pk).update(state=Job.State.PRINTING)
    code, body = call("post", "/printer/resume/mk3/start", keys(), plan=plan)
    assert code == 409 and f"printing job {other.pk}" in body["error"]
    assert ResumePlan.objects.get().state == ResumePlan.State.READY
    assert not Job.objects.filter(resume_of=stopped).exists()


def test_a_run_the_reaper_marked_is_not_resumed_until_its_host_settled_it(
    keys, stopped
) -> None:
    """Marked interrupted when its host fell silent: the host may only be cut off and
    still printing it, and its exact line is in the host's journal."""
    from printers.reaper import LAST_SAVED

    message = (
        f"interrupted: worker host shelf-1 stopped answering at line 30 {LAST_SAVED}"
    )
    Job.objects.filter(pk=stopped.pk).update(message=message)
    stopped.refresh_from_db()
    code, body = call("post", "/printer/resume/mk3", keys(), id=stopped.pk)
    assert code == 409 and "may still be printing it" in body["error"]
    _nothing_changed(stopped)


def test_a_plan_made_before_the_reaper_marked_the_run_does_not_start(
    keys, stopped
) -> None:
    from printers.reaper import LAST_SAVED

    status, body = call("post", "/printer/resume/mk3", keys(), id=stopped.pk)
    plan = body["data"]["id"]
    assert make_plan(plan) == "ready"
    Job.objects.filter(pk=stopped.pk).update(message=f"interrupted {LAST_SAVED}")
    code, body = call("post", "/printer/resume/mk3/start", keys(), plan=plan)
    assert code == 409 and "may still be printing it" in body["error"]
    assert Job.objects.count() == 1


def test_a_file_changed_since_the_run_is_not_resumed(keys, stopped) -> None:
    stopped.path.write_text(TEXT.replace("G1 Z0.6", "G1 Z0.7"))
    code, body = call("post", "/printer/resume/mk3", keys(), id=stopped.pk)
    assert code == 409 and "changed since the run" in body["error"]
    _nothing_changed(stopped)


def test_a_cnc_plan_that_cannot_put_the_files_g92_offset_back_fails_saying_why(
    keys, make_printer, make_job
) -> None:
    """The file zeroed Z with G92 where a machine-coordinate move had left the
    tool: no resume after it can put that zero back, and a guessed one cuts."""
    mill = make_printer(slug="mill", firmware="grbl", state="idle")
    text = "G0 Z5\nG53 G0 Z-1\nG92 Z0\n" + "G1 X1 Z-1 F300\nG1 X2\n" * 20
    job = make_job(mill, text)
    analyse(job.analysis_id)
    Job.objects.filter(pk=job.pk).update(state=Job.State.INTERRUPTED, lines_acked=30)
    status, body = call("post", "/printer/resume/mill", keys(), id=job.pk)
    assert status == 200, body
    assert make_plan(body["data"]["id"]) == "failed"
    plan = ResumePlan.objects.get(pk=body["data"]["id"])
    assert "G92 offset on Z" in plan.reason and plan.preamble == ""
