"""Paths a client or a stored row names never leave the printer's storage.

`jobs.paths.inside` is the one check; the tests below use it through every door:
[ESP700] streams and scripts, stored-file jobs, reprints, exports and uploads.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from django.core.management import CommandError, call_command

from jobs.models import Job
from jobs.paths import PathRefused, inside
from jobs.services import queue_stored_file, reprint, storage_dir


@pytest.mark.parametrize(
    "name",
    [
        "/etc/passwd",
        "//etc/passwd",
        "../x.gcode",
        "a/../../x.gcode",
        "sub/../../../etc/passwd",
        ".uploads/abc.part",
        ".hidden.gcode",
        "",
        " ",
        "a\x00b",
    ],
)
def test_inside_refuses_names_that_leave_or_hide_in_the_storage(tmp_path, name):
    with pytest.raises(PathRefused):
        inside(tmp_path, name)


def test_inside_resolves_plain_and_nested_names_below_the_root(tmp_path):
    assert inside(tmp_path, "a.gcode") == tmp_path.resolve() / "a.gcode"
    assert inside(tmp_path, "sub/b.gcode") == tmp_path.resolve() / "sub" / "b.gcode"
    assert inside(tmp_path, ".uploads/x.part", hidden=True).name == "x.part"


def test_inside_refuses_a_symlink_that_leads_out_and_does_not_say_where(tmp_path):
    root = tmp_path / "store"
    root.mkdir()
    secret = tmp_path / "secret-target.txt"
    secret.write_text("secret\n")
    (root / "link.gcode").symlink_to(secret)
    (root / "dir").symlink_to(tmp_path)

    for name in ("link.gcode", "dir/secret-target.txt"):
        with pytest.raises(PathRefused) as refused:
            inside(root, name)
        assert "secret-target" not in str(refused.value).replace(name, "")


def test_inside_accepts_a_symlink_that_stays_inside(tmp_path):
    (tmp_path / "real.gcode").write_text("G28\n")
    (tmp_path / "alias.gcode").symlink_to(tmp_path / "real.gcode")
    assert inside(tmp_path, "alias.gcode") == (tmp_path / "real.gcode").resolve()


@pytest.mark.django_db
def test_stored_file_jobs_refuse_names_outside_the_storage(make_printer, tmp_path):
    printer = make_printer()
    probe = tmp_path / "probe.gcode"
    probe.write_text("M117 probe\n")
    (storage_dir(printer) / "link.gcode").symlink_to(probe)

    for name in (str(probe), "../../probe.gcode", "link.gcode"):
        with pytest.raises(PathRefused):
            queue_stored_file(printer, name)
    assert not Job.objects.exists()


@pytest.mark.django_db
def test_a_job_row_naming_a_file_outside_the_storage_is_never_read(
    make_printer, make_job, tmp_path
):
    printer = make_printer()
    job = make_job(printer, "G28\n")
    probe = tmp_path / "probe.gcode"
    probe.write_text("M117 probe\n")
    Job.objects.filter(pk=job.pk).update(file="../probe.gcode", state="completed")
    job.refresh_from_db()

    with pytest.raises(PathRefused):
        _ = job.path
    with pytest.raises(PathRefused):
        reprint(job)
    with pytest.raises(CommandError, match="the printer's storage"):
        call_command("export_job", str(job.pk), str(tmp_path / "out.gcode"))
    assert not (tmp_path / "out.gcode").exists()
    assert Job.objects.count() == 1


@pytest.mark.django_db
def test_export_job_refuses_to_write_into_the_job_storage(make_printer, make_job):
    printer = make_printer()
    job = make_job(printer, "G28\nG1 X1\n")
    before = job.path.read_bytes()

    with pytest.raises(CommandError, match="inside the job storage"):
        call_command("export_job", str(job.pk), str(job.path))
    assert job.path.read_bytes() == before


@pytest.mark.django_db
def test_upload_names_that_climb_are_stored_inside_the_storage(make_printer, tmp_path):
    from jobs.services import enqueue_job

    printer = make_printer()
    source = tmp_path / "src.gcode"
    source.write_text("G28\n")
    for name in ("../../evil.gcode", "/etc/cron.d/evil.gcode", "..\\..\\evil.gcode"):
        job = enqueue_job(printer, source, name=name)
        assert job.path.parent == storage_dir(printer).resolve()
    assert not list(tmp_path.glob("evil*"))
    assert not (tmp_path / "jobs" / "evil.gcode").exists()


def test_stored_paths_in_the_tree_are_resolved(tmp_path: Path) -> None:
    # A storage folder that is itself a symlink still works (resolved on both sides).
    real = tmp_path / "real"
    real.mkdir()
    (tmp_path / "alias").symlink_to(real)
    assert inside(tmp_path / "alias", "a.gcode") == real.resolve() / "a.gcode"


@pytest.mark.django_db
def test_upload_names_of_every_dialect_stay_in_the_storage(
    make_printer, django_user_model, client, tmp_path
):
    from django.core.files.uploadedfile import SimpleUploadedFile

    from printhost.access import issue_key
    from printhost.models import PrinterRole, Role

    printer = make_printer(slug="mk3")
    user = django_user_model.objects.create_user("op", password="pw")
    PrinterRole.objects.create(user=user, printer=printer, role=Role.OPERATOR)
    _, key = issue_key(user, "t")
    evil = "../../../evil.gcode"

    def part() -> SimpleUploadedFile:
        return SimpleUploadedFile(evil, b"G28\nG1 X1\n")

    answers = [
        client.post(
            "/printer/job/mk3",
            {"a": "upload", "name": evil, "filename": part()},
            HTTP_X_API_KEY=key,
        ),
        client.post(
            "/p/mk3/api/files/local",
            {"file": part(), "path": "../../..", "print": "false"},
            HTTP_X_API_KEY=key,
        ),
        client.post(
            "/p/mk3/server/files/upload",
            {"file": part(), "path": "../../..", "root": "gcodes"},
            HTTP_X_API_KEY=key,
        ),
    ]
    session = client.post(
        f"/printer/upload/mk3?name={evil}&size=10", HTTP_X_API_KEY=key
    )
    assert session.status_code in (200, 201), session.content
    upload_id = session.json()["data"]["id"]
    answers.append(
        client.patch(
            f"/printer/upload/mk3/{upload_id}",
            b"G28\nG1 X1\n",
            content_type="application/offset+octet-stream",
            HTTP_UPLOAD_OFFSET="0",
            HTTP_X_API_KEY=key,
        )
    )
    for answer in answers:
        assert answer.status_code in (200, 201), answer.content
    storage = storage_dir(printer).resolve()
    jobs = list(Job.objects.filter(printer=printer))
    assert len(jobs) == 4
    for job in jobs:
        assert job.path.parent == storage
        assert "/" not in job.name and ".." not in job.name
    assert not list(tmp_path.rglob("evil.gcode"))


@pytest.mark.django_db
def test_a_name_too_long_for_the_file_system_is_cut_keeping_its_extension(
    make_printer, tmp_path
):
    """300 characters would fail the file system (255 bytes) with an error 500 at
    the upload, or later where a prefix is added (a farm copy): cut to 180."""
    from jobs.services import MAX_NAME, enqueue_job, safe_name

    source = tmp_path / "upload.part"
    source.write_text("G28\n")
    long = "benchy-" + "x" * 300 + ".gcode"
    job = enqueue_job(make_printer(), source, name=long)
    assert job.name == safe_name(long)
    assert len(job.name) == MAX_NAME and job.name.endswith("x.gcode")
    assert job.path.read_text() == "G28\n"
    assert len(safe_name("a" * 300)) == MAX_NAME
