"""A worker host's fetcher over real HTTP: files arrive whole and checked, the cache
stays within its cap, and a job waits (saying why) while its file is not here."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from jobs import hostcache
from jobs.models import Job
from printers.fetcher import Fetcher
from printers.hosts import WorkerHost

pytestmark = pytest.mark.django_db(transaction=True)

GCODE = "G28\n" + "".join(f"G1 X{i % 200} Y{i % 180} F3000\n" for i in range(5000))


@pytest.fixture
def shelf() -> tuple[WorkerHost, str]:
    host = WorkerHost.objects.create(name="shelf-1")
    return host, host.issue_key()


@pytest.fixture
def on_worker_host(settings, live_server, tmp_path: Path) -> Path:
    """This process plays the worker host: files come from the live server."""
    settings.PRINTHOST_CONTROL_URL = live_server.url
    return tmp_path / "cache" / "jobs"


def _fetcher(cache: Path, key: str, cap: int = 10**9, control: str = "") -> Fetcher:
    from django.conf import settings

    return Fetcher(
        "shelf-1",
        control_url=control or settings.PRINTHOST_CONTROL_URL,
        key=key,
        cache=cache,
        cap_bytes=cap,
    )


def _queue(make_printer, make_job, host: WorkerHost, text: str = GCODE) -> Job:
    from django.conf import settings

    control, settings.PRINTHOST_CONTROL_URL = settings.PRINTHOST_CONTROL_URL, ""
    try:  # the control plane stores it (in the job storage)
        return make_job(make_printer(worker_host=host), text)
    finally:
        settings.PRINTHOST_CONTROL_URL = control


def test_a_queued_jobs_file_arrives_checked_and_the_worker_reads_it_from_the_cache(
    shelf, on_worker_host, make_printer, make_job
):
    host, key = shelf
    job = _queue(make_printer, make_job, host)
    stored = Path(job.__class__.objects.get(pk=job.pk).file)
    assert not hostcache.verified(job.sha256)
    assert job.path.name == "missing"  # not here yet: the worker must not start it

    assert _fetcher(on_worker_host, key).step() == 1
    cached = on_worker_host / job.sha256
    assert hashlib.sha256(cached.read_bytes()).hexdigest() == job.sha256
    assert Job.objects.get(pk=job.pk).path == cached
    assert cached.read_text() == GCODE
    assert stored.name  # the row still names the control plane's file
    assert _fetcher(on_worker_host, key).step() == 0  # nothing more to fetch


def test_claim_waits_for_the_file_then_takes_the_job(
    shelf, on_worker_host, make_printer, make_job
):
    from printers.worker import spool

    host, key = shelf
    job = _queue(make_printer, make_job, host)
    assert spool.claim_next(job.printer_id) is None
    assert Job.objects.get(pk=job.pk).state == Job.State.QUEUED
    _fetcher(on_worker_host, key).step()
    claimed = spool.claim_next(job.printer_id)
    assert claimed is not None and claimed.pk == job.pk


def test_a_corrupted_cache_file_is_deleted_and_fetched_again(
    shelf, on_worker_host, make_printer, make_job
):
    host, key = shelf
    job = _queue(make_printer, make_job, host)
    fetcher = _fetcher(on_worker_host, key)
    fetcher.step()
    cached = on_worker_host / job.sha256
    data = bytearray(cached.read_bytes())
    data[500] ^= 0x20  # one flipped bit on a failing SD card
    cached.write_bytes(bytes(data))
    assert hostcache.verified(job.sha256) is None
    assert not cached.exists()
    assert fetcher.step() == 1
    assert hostcache.verified(job.sha256) == cached


def test_a_cut_download_continues_from_its_part(
    shelf, on_worker_host, make_printer, make_job
):
    host, key = shelf
    job = _queue(make_printer, make_job, host)
    on_worker_host.mkdir(parents=True)
    (on_worker_host / f"{job.sha256}.part").write_bytes(GCODE.encode()[:1000])
    assert _fetcher(on_worker_host, key).step() == 1
    assert (on_worker_host / job.sha256).read_text() == GCODE


def test_a_download_with_the_wrong_content_is_refused_and_retried_later(
    shelf, on_worker_host, make_printer, make_job
):
    host, key = shelf
    job = _queue(make_printer, make_job, host)
    on_worker_host.mkdir(parents=True)
    # A part from something else entirely: the whole must not check out.
    (on_worker_host / f"{job.sha256}.part").write_bytes(b"M104 S250\n" * 50)
    fetcher = _fetcher(on_worker_host, key)
    assert fetcher.step() == 0
    assert not (on_worker_host / job.sha256).exists()
    assert not (on_worker_host / f"{job.sha256}.part").exists()
    assert "SHA-256" in Job.objects.get(pk=job.pk).message
    fetcher.retry.clear()
    assert fetcher.step() == 1


@pytest.mark.parametrize(
    ("key", "words"),
    [("ph_host_notthekeyatallxxxxxx", "answered 401"), ("", "answered 401")],
)
def test_a_wrong_key_leaves_the_job_waiting_and_says_why(
    shelf, on_worker_host, make_printer, make_job, key, words
):
    host, _ = shelf
    job = _queue(make_printer, make_job, host)
    assert _fetcher(on_worker_host, key).step() == 0
    message = Job.objects.get(pk=job.pk).message
    assert words in message and "worker host's key" in message
    assert Job.objects.get(pk=job.pk).state == Job.State.QUEUED


def test_an_unreachable_control_plane_is_retried_with_backoff(
    shelf, on_worker_host, make_printer, make_job
):
    from tests.hosts import free_port

    host, key = shelf
    job = _queue(make_printer, make_job, host)
    now = [0.0]
    fetcher = Fetcher(
        "shelf-1", control_url=f"http://127.0.0.1:{free_port()}", key=key,
        cache=on_worker_host, cap_bytes=10**9, clock=lambda: now[0],
    )  # fmt: skip
    assert fetcher.step() == 0
    assert "cannot reach the control plane" in Job.objects.get(pk=job.pk).message
    first = fetcher.retry[job.sha256][0]
    fetcher.step()  # too soon: not tried again
    now[0] = first
    fetcher.step()
    assert fetcher.retry[job.sha256][0] - now[0] == 2 * first


def test_the_cache_keeps_its_cap_but_never_drops_a_file_a_job_needs(
    shelf, on_worker_host, make_printer, make_job
):
    host, key = shelf
    jobs = [
        _queue(make_printer, make_job, host, GCODE + f"M117 job {n}\n")
        for n in range(3)
    ]
    size = len(GCODE) + 20
    fetcher = _fetcher(on_worker_host, key, cap=2 * size)
    assert fetcher.step() == 3  # over the cap, but all three are queued: kept
    assert all((on_worker_host / j.sha256).exists() for j in jobs)
    Job.objects.filter(pk=jobs[0].pk).update(state=Job.State.COMPLETED)
    fetcher.step()
    assert not (on_worker_host / jobs[0].sha256).exists()
    assert all((on_worker_host / j.sha256).exists() for j in jobs[1:])


def test_a_control_url_that_is_not_http_is_refused(shelf, tmp_path):
    with pytest.raises(ValueError, match="http:// or https://"):
        Fetcher(
            "shelf-1", control_url="file:///etc", key="k", cache=tmp_path,
            cap_bytes=1,
        )  # fmt: skip
