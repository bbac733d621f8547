"""The SQLite worker's doorbell (printers/doorbell.py): a named pipe its writers ring."""

from __future__ import annotations

import os
import select
import stat
from pathlib import Path

import pytest

from jobs.commands import send_command
from jobs.models import Job
from printers.doorbell import Doorbell, bell_path, ring, ring_at_commit
from printers.worker.wakeup import Wakeups


def readable(fd: int) -> bool:
    return bool(select.select([fd], [], [], 0)[0])


@pytest.fixture
def bell(storage: Path):
    doorbell = Doorbell(1)
    yield doorbell
    doorbell.close()


def test_a_ring_wakes_the_worker_once_and_a_drain_quiets_it(bell: Doorbell) -> None:
    fd = bell.fileno()
    assert fd is not None
    assert not readable(fd)
    assert ring(1) and ring(1)
    assert readable(fd)
    assert bell.drain() is True
    # The ringers have closed their ends: the pipe does not read as ended.
    assert not readable(fd)
    assert bell.drain() is False


def test_only_its_owner_can_open_the_pipe(bell: Doorbell) -> None:
    bell.fileno()
    mode = bell.path.stat().st_mode
    assert stat.S_ISFIFO(mode)
    assert stat.S_IMODE(mode) & 0o077 == 0
    assert stat.S_IMODE(bell.path.parent.stat().st_mode) == 0o700


def test_nobody_listening_is_not_an_error(storage: Path) -> None:
    assert ring(7) is False  # no pipe
    bell_path(7).parent.mkdir(mode=0o700, exist_ok=True)
    os.mkfifo(bell_path(7), 0o600)
    assert ring(7) is False  # a pipe a killed worker left: no reader


@pytest.mark.parametrize("kind", ["file", "link"])
def test_a_ring_writes_nothing_into_what_is_not_a_pipe(
    storage: Path, tmp_path: Path, kind: str
) -> None:
    target = tmp_path / "precious.txt"
    target.write_text("keep me")
    path = bell_path(3)
    path.parent.mkdir(mode=0o700, exist_ok=True)
    if kind == "file":
        path.write_text("keep me")
    else:
        path.symlink_to(target)
    assert ring(3) is False
    assert path.read_text() == target.read_text() == "keep me"


def test_a_new_worker_replaces_a_killed_ones_pipe_and_keeps_it(storage: Path) -> None:
    old = Doorbell(2)
    old.fileno()
    new = Doorbell(2)
    fd = new.fileno()
    assert fd is not None
    # The old worker's close (it ends late) leaves the new pipe in place.
    old.close()
    assert bell_path(2).exists()
    assert ring(2) and new.drain()
    new.close()
    assert not bell_path(2).exists()
    assert ring(2) is False


def test_a_worker_that_cannot_make_its_pipe_polls(storage: Path) -> None:
    bell_path(4).parent.write_text("not a folder")
    doorbell = Doorbell(4)
    assert doorbell.fileno() is None
    assert doorbell.drain() is False


@pytest.mark.django_db
def test_a_worker_of_its_own_on_sqlite_waits_on_its_doorbell(make_printer) -> None:
    printer = make_printer()
    alone, shared = Wakeups(printer.pk, alone=True), Wakeups(printer.pk)
    try:
        fd = alone.fileno()
        assert fd is not None and alone.listening
        # A worker sharing its connection (tests drive one) polls.
        assert shared.fileno() is None and not shared.listening
        # What was written before the pipe existed is looked for at once.
        assert alone.take(readable=False) is True
        assert alone.take(readable=readable(fd)) is False
        ring(printer.pk)
        assert alone.take(readable=readable(fd)) is True
        assert alone.take(readable=readable(fd)) is False
    finally:
        alone.close()
    assert not bell_path(printer.pk).exists()


@pytest.mark.django_db
def test_a_request_and_a_queued_job_ring_at_commit(
    make_printer, make_job, django_capture_on_commit_callbacks
) -> None:
    printer = make_printer()
    other = make_printer()
    bell = Doorbell(printer.pk)
    fd = bell.fileno()
    assert fd is not None
    try:
        with django_capture_on_commit_callbacks(execute=False) as rings:
            send_command(printer, "M105", origin="test")
        assert not readable(fd), "rung before the commit"
        for callback in rings:
            callback()
        assert bell.drain()

        with django_capture_on_commit_callbacks(execute=True):
            job = make_job(printer, "G1 X1\n")
        assert job.state == Job.State.QUEUED and bell.drain()

        with django_capture_on_commit_callbacks(execute=True):
            Job.objects.filter(pk=job.pk).update(state=Job.State.COMPLETED)
            job.refresh_from_db()
            job.save()  # saved, not queued: nothing to look for
            ring_at_commit(other.pk)  # another printer's bell
        assert not bell.drain()
    finally:
        bell.close()
