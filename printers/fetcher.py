"""A worker host's fetcher: job files from the control plane into the host's cache.

`manage.py fetch_files --worker-host NAME` (started by `runhost --worker-host`),
one loop, no threads. Every second it lists the jobs this host's printers will
print (queued, printing, paused) whose file is not in the cache, and downloads
them in queue order over HTTP(S) from `PRINTHOST_CONTROL_URL/host/files/<job>` with
the host's key (`PRINTHOST_HOST_KEY`):

1. the body is streamed to `<sha256>.part` in the cache, never held in memory; a
   cut download continues from the part's size (`Range`);
2. the part's SHA-256 must equal the job's, or it is deleted and fetched again;
3. it is renamed to `<sha256>` (atomic), where the worker finds it
   (`jobs.hostcache.verified`, which checks the SHA-256 again before printing).

The cache keeps at most `PRINTHOST_FILE_CACHE_BYTES`; the least recently used
files go first, never a file a queued or running job of this host names. A job
waiting for its file says so in its message.
"""

from __future__ import annotations

import json
import logging
import time
import urllib.error
import urllib.request
from dataclasses import dataclass
from typing import TYPE_CHECKING

from django.db import DatabaseError

from jobs import hostcache
from jobs.models import ACTIVE_STATES, Job
from printhost.longrunning import close_failed_connections

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

logger = logging.getLogger("printhost.fetcher")

CHUNK = 256 * 1024
#: Seconds to wait for the control plane's answer or its next bytes.
TIMEOUT = 30.0
#: Delay after a failed download of one file, doubling up to the cap (s).
RETRY_FIRST = 1.0
RETRY_CAP = 60.0
#: The job's message is updated at most this often while its file arrives (s).
MESSAGE_SECONDS = 2.0

_WANTED_STATES = (Job.State.QUEUED, *ACTIVE_STATES)


class FetchFailed(Exception):
    """One download failed; the message says why (it is retried later)."""


@dataclass
class Wanted:
    job_id: int
    sha256: str
    size: int
    queued: bool


class Fetcher:
    """Keeps the cache holding every file this host's printers will print."""

    def __init__(
        self,
        host: str,
        *,
        control_url: str,
        key: str,
        cache: Path,
        cap_bytes: int,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not control_url.startswith(("http://", "https://")):
            raise ValueError(
                f"PRINTHOST_CONTROL_URL={control_url!r}: the control plane's address "
                "starts with http:// or https://"
            )
        self.host = host
        self.control_url = control_url.rstrip("/")
        self.key = key
        self.cache = cache
        self.cap_bytes = cap_bytes
        self.clock = clock
        #: sha256 -> (monotonic time of the next try, current delay)
        self.retry: dict[str, tuple[float, float]] = {}
        self._message_at = 0.0
        self.fetched = 0

    def wanted(self) -> list[Wanted]:
        """This host's jobs that print a stored file, in queue order."""
        rows = (
            Job.objects.filter(
                printer__worker_host__name=self.host, state__in=_WANTED_STATES
            )
            .exclude(kind=Job.Kind.SD_PRINT)
            .exclude(file="")
            .order_by("printer_id", "position", "id")
            .values_list("pk", "sha256", "size_bytes", "state")
        )
        return [
            Wanted(pk, sha, size, state == Job.State.QUEUED)
            for pk, sha, size, state in rows
            if hostcache.valid_sha256(sha)
        ]

    def step(self) -> int:
        """One pass: fetch what is missing (each file once), then trim the cache.

        Returns how many files arrived.
        """
        wanted = self.wanted()
        arrived = 0
        seen: set[str] = set()
        for item in wanted:
            if item.sha256 in seen or (self.cache / item.sha256).exists():
                seen.add(item.sha256)
                continue
            seen.add(item.sha256)
            if self.clock() < self.retry.get(item.sha256, (0.0, 0.0))[0]:
                continue
            try:
                self.fetch(item)
            except FetchFailed as error:
                self._failed(item, str(error))
                continue
            self.retry.pop(item.sha256, None)
            arrived += 1
        self.trim(keep=seen)
        return arrived

    def fetch(self, item: Wanted) -> Path:
        """Download one job's file into the cache, checked; FetchFailed says why."""
        self.cache.mkdir(parents=True, exist_ok=True)
        part = self.cache / f"{item.sha256}.part"
        have = part.stat().st_size if part.exists() else 0
        request = urllib.request.Request(
            f"{self.control_url}/host/files/{item.job_id}",
            headers={"Authorization": f"Bearer {self.key}"},
        )
        if have:
            request.add_header("Range", f"bytes={have}-")
        try:
            with urllib.request.urlopen(request, timeout=TIMEOUT) as response:
                if response.status != 206:
                    have = 0  # the whole file came back: start the part again
                announced = response.headers.get("X-Printhost-Sha256", "")
                if announced and announced != item.sha256:
                    raise FetchFailed(
                        f"the control plane's file has SHA-256 {announced[:12]}…, "
                        f"the job names {item.sha256[:12]}…"
                    )
                self._copy(response, part, append=bool(have), item=item, have=have)
        except urllib.error.HTTPError as error:
            raise FetchFailed(f"the control plane answered {error.code}: "
                              f"{_error_text(error)}") from None  # fmt: skip
        except (urllib.error.URLError, OSError, TimeoutError) as error:
            raise FetchFailed(f"cannot reach the control plane: {error}") from None
        digest = hostcache.sha256_of(part)
        if digest != item.sha256:
            part.unlink(missing_ok=True)
            raise FetchFailed(
                f"the download's SHA-256 is {digest[:12]}…, not the job's "
                f"{item.sha256[:12]}…; fetching it again"
            )
        target = self.cache / item.sha256
        part.replace(target)
        self.fetched += 1
        logger.info("host %s: job %s's file arrived", self.host, item.job_id)
        self._say(item.job_id, "")
        return target

    def _copy(
        self, response: object, part: Path, *, append: bool, item: Wanted, have: int
    ) -> None:
        done = have
        with part.open("ab" if append else "wb") as out:
            while chunk := response.read(CHUNK):  # type: ignore[attr-defined]
                out.write(chunk)
                done += len(chunk)
                if self.clock() >= self._message_at and item.size:
                    self._message_at = self.clock() + MESSAGE_SECONDS
                    share = min(100, round(100 * done / item.size))
                    self._say(
                        item.job_id,
                        f"its file is on its way to worker host {self.host}: {share} %",
                    )

    def _failed(self, item: Wanted, reason: str) -> None:
        _, delay = self.retry.get(item.sha256, (0.0, RETRY_FIRST / 2))
        delay = min(delay * 2, RETRY_CAP)
        self.retry[item.sha256] = (self.clock() + delay, delay)
        logger.warning(
            "host %s: job %s's file: %s; trying again in %.0f s",
            self.host,
            item.job_id,
            reason,
            delay,
        )
        self._say(
            item.job_id,
            f"waiting for its file on worker host {self.host}: {reason}",
        )

    def _say(self, job_id: int, message: str) -> None:
        """A queued job's message says where its file is (never a running job's)."""
        Job.objects.filter(pk=job_id, state=Job.State.QUEUED).update(message=message)

    def trim(self, keep: set[str]) -> list[str]:
        """Remove least recently used files until the cache fits its cap.

        Files in *keep* (named by this host's queued and running jobs) stay even
        if the cap is exceeded; so do parts being written. Returns what went.
        """
        if not self.cache.is_dir():
            return []
        files = [
            (path.stat().st_mtime, path.stat().st_size, path)
            for path in self.cache.iterdir()
            if path.is_file() and hostcache.valid_sha256(path.name)
        ]
        total = sum(size for _, size, _ in files)
        removed: list[str] = []
        for _, size, path in sorted(files):
            if total <= self.cap_bytes:
                break
            if path.name in keep:
                continue
            path.unlink(missing_ok=True)
            total -= size
            removed.append(path.name)
        if removed:
            logger.info("host %s: cache trimmed: %d file(s)", self.host, len(removed))
        return removed

    def run(self, should_stop: Callable[[], bool], interval: float = 1.0) -> None:
        """Step every *interval* until *should_stop*; a database away is waited out."""
        while not should_stop():
            began = self.clock()
            try:
                close_failed_connections()
                self.step()
            except DatabaseError as error:
                logger.warning("host %s: database unavailable: %s", self.host, error)
            wait = interval - (self.clock() - began)
            if wait > 0:
                time.sleep(wait)


def _error_text(error: urllib.error.HTTPError) -> str:
    try:
        body = error.read(2000).decode("utf-8", "replace")
    except OSError:
        return error.reason or ""
    try:
        return str(json.loads(body).get("error") or body)
    except (ValueError, AttributeError):
        return body.strip()[:200]
