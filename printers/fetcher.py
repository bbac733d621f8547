"""A worker host's fetcher: job files from the control plane into the host's cache.

`manage.py fetch_files --worker-host NAME` (started by `runhost --worker-host`),
one loop, no threads. Every second it lists the jobs this host's printers will
print (queued, printing, paused) whose file is not in the cache, and downloads
them in queue order over HTTP(S) from `PRINTHOST_CONTROL_URL/host/files/<job>` with
the host's key (`PRINTHOST_HOST_KEY`):

1. the body is streamed to `<sha256>.part` in the cache, never held in memory; a
   cut download continues from the part's size (`Range`). The part is locked
   while it is written (a second fetcher on the host leaves it alone), never
   grows past the job's size, and one download takes at most TIMEOUT plus the
   size at SLOWEST_RATE (a slower one stops and continues on a later pass);
2. the part's SHA-256 must equal the job's, or it is deleted and fetched again;
3. it is renamed to `<sha256>` (atomic), where the worker finds it
   (`jobs.hostcache.verified`, which checks the SHA-256 again before printing).

The host's key goes to the control plane's address only: a redirect is refused
(it would carry the key elsewhere). The cache keeps at most
`PRINTHOST_FILE_CACHE_BYTES`, parts included; the least recently used files go
first, never a file a queued or running job of this host names, and a part no
such job names is deleted. A job waiting for its file says so in its message.
"""

from __future__ import annotations

import contextlib
import fcntl
import http.client
import json
import logging
import time
import urllib.error
import urllib.request
from dataclasses import dataclass
from typing import TYPE_CHECKING

from django.db import DatabaseError

from jobs import hostcache
from jobs.models import HOST_FILE_STATES, Job
from printhost.longrunning import close_failed_connections

if TYPE_CHECKING:
    from collections.abc import Callable
    from email.message import Message
    from pathlib import Path
    from typing import IO, BinaryIO

logger = logging.getLogger("printhost.fetcher")

CHUNK = 256 * 1024
#: Seconds to wait for the control plane's answer or its next bytes.
TIMEOUT = 30.0
#: One download may take TIMEOUT plus its size at this rate (bytes/s); a slower
#: one stops (the part stays) and goes on at a later pass, so one slow file does
#: not hold back the others.
SLOWEST_RATE = 50_000
#: Delay after a failed download of one file, doubling up to the cap (s).
RETRY_FIRST = 1.0
RETRY_CAP = 60.0
#: The job's message is updated at most this often while its file arrives (s).
MESSAGE_SECONDS = 2.0


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
                printer__worker_host__name=self.host, state__in=HOST_FILE_STATES
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
        part = self.cache / f"{item.sha256}.part"
        target = self.cache / item.sha256
        try:
            self.cache.mkdir(parents=True, exist_ok=True)
            with part.open("ab") as out:
                _lock(out)  # held to the rename: no other fetcher writes it meanwhile
                if not item.size or out.tell() < item.size:
                    self._download(item, out)
                digest = hostcache.sha256_of(part)
                if digest != item.sha256:
                    part.unlink(missing_ok=True)
                    raise FetchFailed(
                        f"the download's SHA-256 is {digest[:12]}…, not the job's "
                        f"{item.sha256[:12]}…; fetching it again"
                    )
                part.replace(target)
        except OSError as error:
            raise FetchFailed(f"cannot write the cache: {error}") from None
        self.fetched += 1
        logger.info("host %s: job %s's file arrived", self.host, item.job_id)
        self._say(item.job_id, "")
        return target

    def _download(self, item: Wanted, out: BinaryIO) -> None:
        """Append the rest of the file to *out* (the part, open and locked)."""
        have = out.tell()
        request = urllib.request.Request(f"{self.control_url}/host/files/{item.job_id}")
        # Unredirected: should a redirect get past _OPENER, the key stays here.
        request.add_unredirected_header("Authorization", f"Bearer {self.key}")
        if have:
            request.add_header("Range", f"bytes={have}-")
        try:
            with _OPENER.open(request, timeout=TIMEOUT) as response:
                if response.status != 206:
                    _restart(out)  # the whole file came back: start the part again
                announced = response.headers.get("X-Printhost-Sha256", "")
                if announced and announced != item.sha256:
                    raise FetchFailed(
                        f"the control plane's file has SHA-256 {announced[:12]}…, "
                        f"the job names {item.sha256[:12]}…"
                    )
                self._copy(response, out, item=item)
        except urllib.error.HTTPError as error:
            if error.code == 416:  # the part is longer than the file: start again
                _restart(out)
            raise FetchFailed(f"the control plane answered {error.code}: "
                              f"{_error_text(error)}") from None  # fmt: skip
        except (OSError, http.client.HTTPException) as error:  # URLError included
            raise FetchFailed(f"cannot reach the control plane: {error}") from None

    def _copy(self, response: BinaryIO, out: BinaryIO, *, item: Wanted) -> None:
        started = self.clock()
        deadline = started + TIMEOUT + item.size / SLOWEST_RATE
        done = out.tell()
        while chunk := _read(response):
            if item.size and done + len(chunk) > item.size:
                _restart(out)
                raise FetchFailed(
                    f"the control plane sent more than the job's {item.size} bytes; "
                    "fetching it again"
                )
            _write(out, chunk)
            done += len(chunk)
            now = self.clock()
            if now >= deadline and done < item.size:
                raise FetchFailed(
                    f"the download is slower than {SLOWEST_RATE // 1000} kB/s "
                    f"({done} of {item.size} bytes after {now - started:.0f} s); "
                    "it goes on from there at the next try"
                )
            if now >= self._message_at and item.size:
                self._message_at = now + MESSAGE_SECONDS
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
        if the cap is exceeded, and so do their parts (downloads under way or
        cut short); a part no such job names goes. Returns what went.
        """
        if not self.cache.is_dir():
            return []
        files, parts = [], []
        for path in self.cache.iterdir():
            name = path.name
            sha, is_part = name.removesuffix(".part"), name.endswith(".part")
            if not hostcache.valid_sha256(sha):
                continue
            with contextlib.suppress(FileNotFoundError):  # gone meanwhile
                stat = path.stat()
                if is_part:
                    parts.append((stat.st_size, path, sha))
                else:
                    files.append((stat.st_mtime, stat.st_size, path))
        removed: list[str] = []
        total = sum(size for _, size, _ in files)
        for size, path, sha in parts:
            if sha in keep:
                total += size
            elif _unlink_unlocked(path):
                removed.append(path.name)
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


class _RefuseRedirects(urllib.request.HTTPRedirectHandler):
    """A redirect would take the host's key to another address: refused."""

    def redirect_request(
        self,
        req: urllib.request.Request,
        fp: IO[bytes],
        code: int,
        msg: str,
        headers: Message,
        newurl: str,
    ) -> urllib.request.Request | None:
        fp.close()
        raise FetchFailed(
            f"the control plane redirected the download to {newurl} ({code}); "
            "set PRINTHOST_CONTROL_URL to the address that serves it"
        )


_OPENER = urllib.request.build_opener(_RefuseRedirects)


def _restart(out: BinaryIO) -> None:
    """Empty the part: what comes next is the file from its start."""
    try:
        out.seek(0)
        out.truncate()
    except OSError as error:
        raise FetchFailed(f"cannot write the cache: {error}") from None


def _write(out: BinaryIO, chunk: bytes) -> None:
    """Append *chunk* to the part (a full disk is the cache's error, not the
    network's)."""
    try:
        out.write(chunk)
        out.flush()
    except OSError as error:
        raise FetchFailed(f"cannot write the cache: {error}") from None


def _read(response: BinaryIO) -> bytes:
    """The next chunk of the body (a network error, not the cache's)."""
    try:
        return response.read(CHUNK)
    except (OSError, http.client.HTTPException) as error:
        raise FetchFailed(f"the download was cut: {error}") from None


def _lock(out: BinaryIO) -> None:
    """Take the part for this fetcher; FetchFailed when another one writes it."""
    try:
        fcntl.flock(out.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise FetchFailed("another fetcher on this host is writing it") from None


def _unlink_unlocked(path: Path) -> bool:
    """Delete a part no fetcher is writing; whether it went."""
    try:
        with path.open("rb") as part:
            fcntl.flock(part.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            path.unlink()
    except (BlockingIOError, FileNotFoundError):
        return False
    return True


def _error_text(error: urllib.error.HTTPError) -> str:
    try:
        body = error.read(2000).decode("utf-8", "replace")
    except OSError:
        return error.reason or ""
    try:
        return str(json.loads(body).get("error") or body)
    except (ValueError, AttributeError):
        return body.strip()[:200]
