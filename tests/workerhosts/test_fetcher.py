"""A worker host's fetcher over real HTTP: files arrive whole and checked, the cache
stays within its cap, and a job waits (saying why) while its file is not here."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from jobs import hostcache
from jobs.models import Job
from printers.fetcher import RETRY_CAP, Fetcher
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


def test_a_whole_part_left_by_a_killed_fetcher_is_checked_without_asking_again(
    shelf, on_worker_host, make_printer, make_job
):
    """Killed between the last byte and the rename: the part is the whole file, and
    a Range from its end would only get a 416. It is checked and used as it is."""
    from tests.hosts import free_port

    host, key = shelf
    job = _queue(make_printer, make_job, host)
    on_worker_host.mkdir(parents=True)
    (on_worker_host / f"{job.sha256}.part").write_bytes(GCODE.encode())
    unreachable = f"http://127.0.0.1:{free_port()}"
    assert _fetcher(on_worker_host, key, control=unreachable).step() == 1
    assert hostcache.verified(job.sha256) == on_worker_host / job.sha256
    assert not (on_worker_host / f"{job.sha256}.part").exists()


def test_a_part_longer_than_the_file_is_started_again(
    shelf, on_worker_host, make_printer, make_job
):
    host, key = shelf
    job = _queue(make_printer, make_job, host)
    Job.objects.filter(pk=job.pk).update(size_bytes=len(GCODE) + 1000)
    on_worker_host.mkdir(parents=True)
    part = on_worker_host / f"{job.sha256}.part"
    part.write_bytes(GCODE.encode() + b"M117 left over\n")
    fetcher = _fetcher(on_worker_host, key)
    assert fetcher.step() == 0
    assert "answered 416" in Job.objects.get(pk=job.pk).message
    assert part.stat().st_size == 0  # else every later try gets its 416 again
    fetcher.retry.clear()
    assert fetcher.step() == 1
    assert (on_worker_host / job.sha256).read_text() == GCODE


def test_a_body_longer_than_the_job_is_cut_off_and_not_kept(
    shelf, on_worker_host, make_printer, make_job
):
    host, key = shelf
    job = _queue(make_printer, make_job, host)
    Job.objects.filter(pk=job.pk).update(size_bytes=1000)
    assert _fetcher(on_worker_host, key).step() == 0
    message = Job.objects.get(pk=job.pk).message
    assert "more than the job's 1000 bytes" in message
    assert (on_worker_host / f"{job.sha256}.part").stat().st_size == 0


def test_a_download_slower_than_its_time_stops_and_goes_on_later(
    shelf, on_worker_host, make_printer, make_job
):
    from printers import fetcher as fetching

    host, key = shelf
    text = GCODE * 8  # several chunks
    job = _queue(make_printer, make_job, host, text)
    hours = iter(range(0, 10**6, 3600))
    slow = Fetcher(
        "shelf-1", control_url=_control(), key=key, cache=on_worker_host,
        cap_bytes=10**9, clock=lambda: float(next(hours)),
    )  # fmt: skip
    assert slow.step() == 0
    assert "slower than" in Job.objects.get(pk=job.pk).message
    part = on_worker_host / f"{job.sha256}.part"
    assert part.stat().st_size == fetching.CHUNK  # what came is kept
    assert _fetcher(on_worker_host, key).step() == 1
    assert (on_worker_host / job.sha256).read_text() == text


def test_a_cache_it_cannot_write_is_said_to_be_the_cache_not_the_network(
    shelf, on_worker_host, make_printer, make_job
):
    host, key = shelf
    job = _queue(make_printer, make_job, host)
    (on_worker_host / f"{job.sha256}.part").mkdir(parents=True)  # not writable
    assert _fetcher(on_worker_host, key).step() == 0
    message = Job.objects.get(pk=job.pk).message
    assert "cannot write the cache" in message
    assert "control plane" not in message


def test_parts_count_against_the_cap_and_a_part_no_job_wants_is_deleted(
    shelf, on_worker_host, make_printer, make_job
):
    host, key = shelf
    job = _queue(make_printer, make_job, host)
    on_worker_host.mkdir(parents=True)
    kept_part = on_worker_host / f"{job.sha256}.part"
    kept_part.write_bytes(GCODE.encode()[:600])  # cut short, waiting to go on
    orphan = on_worker_host / f"{'ab' * 32}.part"  # its job ended meanwhile
    orphan.write_bytes(b"x" * 5000)
    old = on_worker_host / ("c" * 64)  # an older job's file, wanted no more
    old.write_bytes(b"y" * 600)
    fetcher = _fetcher(on_worker_host, key, cap=1000)
    fetcher.retry[job.sha256] = (float("inf"), RETRY_CAP)  # not now
    fetcher.step()
    assert kept_part.stat().st_size == 600
    assert not orphan.exists()
    assert not old.exists()  # 600 + the part's 600 is over the cap of 1000


def test_a_part_another_fetcher_writes_is_left_alone(
    shelf, on_worker_host, make_printer, make_job
):
    import fcntl

    host, key = shelf
    job = _queue(make_printer, make_job, host)
    on_worker_host.mkdir(parents=True)
    part = on_worker_host / f"{job.sha256}.part"
    orphan = on_worker_host / f"{'ab' * 32}.part"
    with part.open("ab") as mine, orphan.open("ab") as theirs:
        fcntl.flock(mine.fileno(), fcntl.LOCK_EX)
        fcntl.flock(theirs.fileno(), fcntl.LOCK_EX)
        assert _fetcher(on_worker_host, key).step() == 0
        assert orphan.exists()  # being written: not the trim's to delete
    assert "another fetcher" in Job.objects.get(pk=job.pk).message
    assert part.stat().st_size == 0


def test_a_redirect_is_refused_and_the_key_never_leaves_the_control_plane(
    shelf, on_worker_host, make_printer, make_job
):
    import threading
    from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

    host, key = shelf
    job = _queue(make_printer, make_job, host)
    seen: list[str | None] = []

    class Elsewhere(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            seen.append(self.headers.get("Authorization"))
            self.send_response(404)
            self.end_headers()

        def log_message(self, *args: object) -> None:
            pass

    other = ThreadingHTTPServer(("127.0.0.1", 0), Elsewhere)

    class Redirecting(Elsewhere):
        def do_GET(self) -> None:
            self.send_response(302)
            self.send_header("Location", f"http://127.0.0.1:{other.server_port}/x")
            self.end_headers()

    control = ThreadingHTTPServer(("127.0.0.1", 0), Redirecting)
    for server in (other, control):
        threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        url = f"http://127.0.0.1:{control.server_port}"
        assert _fetcher(on_worker_host, key, control=url).step() == 0
    finally:
        for server in (other, control):
            server.shutdown()
            server.server_close()
    assert seen == []
    assert "redirected" in Job.objects.get(pk=job.pk).message


def _control() -> str:
    from django.conf import settings

    return settings.PRINTHOST_CONTROL_URL
