"""Web request latency for /metrics: a histogram every daphne process adds to.

A control plane may run several daphne processes behind one proxy, and a scrape
reaches one of them. So the histogram uses prometheus-client's multiprocess mode:
each process keeps its counts in a file of its own (`histogram_<pid>.db`, memory
mapped) in `PRINTHOST_METRICS_DIR`, and a scrape sums every file of the folder, so
any process answers for all of them; labelling by process instead would show only
the one that answered. The folder is per computer (under the data directory);
daphne processes on other computers keep their own and are scraped there.

prometheus-client picks the mode when it is imported, from the environment
variable `PROMETHEUS_MULTIPROC_DIR`; printhost's processes import it long after
start-up, so `_multiprocess_values` sets the variable from PRINTHOST_METRICS_DIR
and switches the library's value class here, before the histogram exists. Only
this histogram lives in those files: the other series are read at scrape time.

A process that ends leaves its file, so the sums never go down (a counter that
fell would read as a restart). `compact` folds the files of processes that are gone
into one `histogram_archive.db` (under an exclusive lock that every scrape's read
takes shared), so the folder holds one file per live process plus one.

Labels: `method`, `route` (the URL pattern, so that the series stay few: `unmatched`
for a 404) and `status` (`2xx`...). The time runs from the request reaching Django
to its response (a streamed file's first bytes).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from asgiref.sync import iscoroutinefunction, markcoroutinefunction
from django.conf import settings
from prometheus_client import Histogram, values
from prometheus_client.mmap_dict import MmapedDict, mmap_key
from prometheus_client.multiprocess import MultiProcessCollector

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

    from django.http import HttpRequest, HttpResponse
    from prometheus_client import Metric

#: Seconds; a print server's pages answer in milliseconds, uploads take longer.
BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0)
METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"})
ARCHIVE = "histogram_archive.db"
LOCK = "lock"


def figures_dir() -> Path:
    """The folder of the per-process files, made if missing."""
    folder = Path(settings.PRINTHOST_METRICS_DIR)
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _multiprocess_values() -> None:
    """Make sure the histogram below is kept in the per-process files."""
    os.environ["PROMETHEUS_MULTIPROC_DIR"] = str(figures_dir())
    if not getattr(values.ValueClass, "_multiprocess", False):
        values.ValueClass = values.MultiProcessValue()


_multiprocess_values()

REQUEST_SECONDS = Histogram(
    "printhost_http_request_duration_seconds",
    "Time from a request reaching Django to its response",
    ["method", "route", "status"],
    buckets=BUCKETS,
)


def route_of(request: HttpRequest) -> str:
    """The URL pattern that answered, or `unmatched`."""
    match = getattr(request, "resolver_match", None)
    route = getattr(match, "route", "") if match is not None else ""
    return f"/{route}" if route else "unmatched"


def record(request: HttpRequest, response: HttpResponse, seconds: float) -> None:
    """Add one request to the histogram."""
    method = request.method if request.method in METHODS else "other"
    status = f"{response.status_code // 100}xx"
    REQUEST_SECONDS.labels(method, route_of(request), status).observe(seconds)


def request_latency(
    get_response: Callable[[HttpRequest], Any],
) -> Callable[[HttpRequest], Any]:
    """Middleware (first in the list): time every request, sync or async."""
    if iscoroutinefunction(get_response):

        async def timed_async(request: HttpRequest) -> HttpResponse:
            start = time.perf_counter()
            response = await get_response(request)
            record(request, response, time.perf_counter() - start)
            return response

        return markcoroutinefunction(timed_async)

    def timed(request: HttpRequest) -> HttpResponse:
        start = time.perf_counter()
        response = get_response(request)
        record(request, response, time.perf_counter() - start)
        return response

    return timed


request_latency.sync_capable = True  # type: ignore[attr-defined]
request_latency.async_capable = True  # type: ignore[attr-defined]


@contextlib.contextmanager
def _locked(folder: Path, mode: int) -> Iterator[bool]:
    """The folder's lock in *mode* (fcntl.LOCK_SH / LOCK_EX, maybe | LOCK_NB)."""
    with (folder / LOCK).open("a") as handle:
        try:
            fcntl.flock(handle, mode)
        except BlockingIOError:
            yield False
            return
        try:
            yield True
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _gone(path: Path) -> bool:
    """A `<type>_<pid>.db` file whose process has ended."""
    pid_text = path.stem.rpartition("_")[2]
    if not pid_text.isdigit() or int(pid_text) == os.getpid():
        return False
    try:
        os.kill(int(pid_text), 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    return False


def compact(folder: Path) -> int:
    """Fold the histogram files of ended processes into the archive; how many.

    1. Take the lock without waiting (another scrape compacting: skip).
    2. Merge the ended processes' files and the archive (buckets not accumulated,
       the files' own form), write them to a new archive file, swap it in.
    3. Remove the folded files. Readers hold the lock shared, so none sees the
       archive and a folded file at once.
    """
    with _locked(folder, fcntl.LOCK_EX | fcntl.LOCK_NB) as held:
        if not held:
            return 0
        ended = [p for p in folder.glob("histogram_*.db") if p.name != ARCHIVE]
        ended = [p for p in ended if _gone(p)]
        if not ended:
            return 0
        archive = folder / ARCHIVE
        sources = [*ended, archive] if archive.exists() else ended
        merged = MultiProcessCollector.merge(
            [str(p) for p in sources], accumulate=False
        )
        fresh = folder / "histogram_archive.new"
        fresh.unlink(missing_ok=True)
        store = MmapedDict(str(fresh))
        try:
            for metric in merged:
                for sample in metric.samples:
                    labels = sample.labels
                    key = mmap_key(
                        metric.name, sample.name, list(labels), list(labels.values()),
                        metric.documentation,
                    )  # fmt: skip
                    store.write_value(key, sample.value, 0.0)
        finally:
            store.close()
        fresh.replace(archive)
        for path in ended:
            path.unlink(missing_ok=True)
        return len(ended)


def written_dir() -> Path:
    """The folder this process's histogram is kept in (PRINTHOST_METRICS_DIR, as
    `_multiprocess_values` put it in the environment)."""
    folder = Path(os.environ.get("PROMETHEUS_MULTIPROC_DIR") or figures_dir())
    folder.mkdir(parents=True, exist_ok=True)
    return folder


class WebCollector:
    """The request histogram summed over every process's file (and the archive)."""

    def collect(self) -> Iterator[Metric]:
        folder = written_dir()
        compact(folder)
        with _locked(folder, fcntl.LOCK_SH):
            families = list(MultiProcessCollector(None, path=str(folder)).collect())
        yield from families
