"""GET /host/files/<job>: a worker host fetches its own jobs' files, and nothing else."""

from __future__ import annotations

import hashlib

import pytest

from printers.hosts import WorkerHost

GCODE = "G28\n" + "".join(f"G1 X{i} Y{i} F3000\n" for i in range(200))


@pytest.fixture
def shelf(db: None) -> tuple[WorkerHost, str]:
    host = WorkerHost.objects.create(name="shelf-1")
    return host, host.issue_key()


def _get(client, job_id: int, key: str = "", **headers: str):
    if key:
        headers["HTTP_AUTHORIZATION"] = f"Bearer {key}"
    return client.get(f"/host/files/{job_id}", **headers)


def test_the_printers_host_gets_the_file_and_its_sha256(
    client, shelf, make_printer, make_job
):
    host, key = shelf
    job = make_job(make_printer(worker_host=host), GCODE)
    response = _get(client, job.pk, key)
    assert response.status_code == 200
    body = b"".join(response.streaming_content)
    assert body == job.path.read_bytes()
    assert response["X-Printhost-Sha256"] == hashlib.sha256(body).hexdigest()
    assert response["X-Printhost-Sha256"] == job.sha256


def test_a_range_continues_a_cut_download(client, shelf, make_printer, make_job):
    host, key = shelf
    job = make_job(make_printer(worker_host=host), GCODE)
    whole = job.path.read_bytes()
    response = _get(client, job.pk, key, HTTP_RANGE="bytes=100-")
    assert response.status_code == 206
    assert b"".join(response.streaming_content) == whole[100:]
    assert response["Content-Range"] == f"bytes 100-{len(whole) - 1}/{len(whole)}"
    beyond = _get(client, job.pk, key, HTTP_RANGE=f"bytes={len(whole)}-")
    assert beyond.status_code == 416
    # More digits than int() reads (Python refuses 4,300 and more): past the end.
    far = _get(client, job.pk, key, HTTP_RANGE=f"bytes={'9' * 5000}-")
    assert far.status_code == 416


@pytest.mark.parametrize(
    ("authorization", "status"),
    [
        ("", 401),
        ("Bearer ph_host_wrongwrongwrongwrong", 401),
        ("Basic c2hlbGY6a2V5", 401),
    ],
)
def test_without_the_hosts_key_nothing_is_served(
    client, shelf, make_printer, make_job, authorization, status
):
    host, _ = shelf
    job = make_job(make_printer(worker_host=host), GCODE)
    headers = {"HTTP_AUTHORIZATION": authorization} if authorization else {}
    response = client.get(f"/host/files/{job.pk}", **headers)
    assert response.status_code == status
    assert "key" in response.json()["error"]


def test_a_user_api_key_is_not_a_host_key(client, shelf, make_printer, make_job):
    from django.contrib.auth import get_user_model

    from printhost.access import issue_key

    host, _ = shelf
    job = make_job(make_printer(worker_host=host), GCODE)
    admin = get_user_model().objects.create_superuser("root", password="root")
    _, user_key = issue_key(admin, "test")
    assert _get(client, job.pk, user_key).status_code == 401
    client.force_login(admin)
    assert client.get(f"/host/files/{job.pk}").status_code == 401


def test_another_hosts_job_is_not_found(client, shelf, make_printer, make_job):
    host, key = shelf
    other = WorkerHost.objects.create(name="shelf-2")
    theirs = make_job(make_printer(worker_host=other), GCODE)
    local = make_job(make_printer(), GCODE)
    for job in (theirs, local):
        response = _get(client, job.pk, key)
        assert response.status_code == 404
        assert "shelf-1 prints no job" in response.json()["error"]


def test_a_disabled_host_and_a_rotated_key_are_refused(
    client, shelf, make_printer, make_job
):
    host, key = shelf
    job = make_job(make_printer(worker_host=host), GCODE)
    new_key = host.issue_key()
    assert _get(client, job.pk, key).status_code == 401
    assert _get(client, job.pk, new_key).status_code == 200
    WorkerHost.objects.filter(pk=host.pk).update(enabled=False)
    assert _get(client, job.pk, new_key).status_code == 403


def test_a_removed_file_is_gone_not_an_error(client, shelf, make_printer, make_job):
    host, key = shelf
    job = make_job(make_printer(worker_host=host), GCODE)
    job.path.unlink()
    response = _get(client, job.pk, key)
    assert response.status_code == 410
    assert "no longer stored" in response.json()["error"]


def test_only_get_is_answered(client, shelf, make_printer, make_job):
    host, key = shelf
    job = make_job(make_printer(worker_host=host), GCODE)
    response = client.post(f"/host/files/{job.pk}", HTTP_AUTHORIZATION=f"Bearer {key}")
    assert response.status_code == 405


@pytest.mark.parametrize(
    "state", ["stored", "completed", "aborted", "failed", "interrupted"]
)
def test_a_job_that_ended_is_not_served_even_to_its_printers_host(
    client, shelf, make_printer, make_job, state
):
    """The host prints it no more: an ended job's file (perhaps printed while the
    printer was another host's) is not the host's to read."""
    from jobs.models import Job

    host, key = shelf
    job = make_job(make_printer(worker_host=host), GCODE)
    assert _get(client, job.pk, key).status_code == 200
    Job.objects.filter(pk=job.pk).update(state=state)
    response = _get(client, job.pk, key)
    assert response.status_code == 404
    assert f"prints no job {job.pk}" in response.json()["error"]
