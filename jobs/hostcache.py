"""Where a job's file is on the computer that prints it.

On the control plane (and on a one-computer set-up) a job's file is in the job
storage (`Job.path`). A worker host has no share of that disk: its fetcher
(`printers/fetcher.py`) copies each file it will print from the control plane into
`<data dir>/cache/jobs/<sha256>`, and the worker prints from there once the file's
SHA-256 is checked (`verified`). A host is a worker host when
`PRINTHOST_CONTROL_URL` names its control plane.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from django.conf import settings

#: Files are hashed in blocks of this many bytes.
HASH_BLOCK = 1024 * 1024
_SHA256_HEX = frozenset("0123456789abcdef")

#: (path, size, mtime_ns) of cached files whose SHA-256 this process checked.
_checked: set[tuple[str, int, int]] = set()


def on_worker_host() -> bool:
    """This process runs on a worker host (files come from the control plane)."""
    return bool(settings.PRINTHOST_CONTROL_URL)


def cache_dir() -> Path:
    return Path(settings.DATA_DIR) / "cache" / "jobs"


def valid_sha256(text: str) -> bool:
    return len(text) == 64 and set(text) <= _SHA256_HEX


def cached_path(sha256: str) -> Path:
    """The cache's file for *sha256* (ValueError for anything but 64 hex digits:
    the name comes from a database row and must not make a path of its own)."""
    if not valid_sha256(sha256):
        raise ValueError(f"not a SHA-256: {sha256!r}")
    return cache_dir() / sha256


def sha256_of(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as file:
        while block := file.read(HASH_BLOCK):
            digest.update(block)
    return digest.hexdigest()


def verified(sha256: str) -> Path | None:
    """The cached file for *sha256* if its content has that SHA-256, else None.

    A file whose content does not match (a torn copy, a failing SD card) is
    deleted, so the fetcher fetches it again. Each file is hashed once per
    process while its size and modification time stay the same; a check also
    marks it used (its modification time), which the cache's eviction reads.
    """
    try:
        path = cached_path(sha256)
        stat = path.stat()
    except (ValueError, OSError):
        return None
    key = (str(path), stat.st_size, stat.st_mtime_ns)
    if key not in _checked and sha256_of(path) != sha256:
        path.unlink(missing_ok=True)
        return None
    os.utime(path)
    _checked.discard(key)
    _checked.add((str(path), stat.st_size, path.stat().st_mtime_ns))
    return path


def local_path(file_path: Path, sha256: str) -> Path:
    """Where this computer reads a job's file: the job storage's *file_path* on
    the control plane, the checked cache file on a worker host (the cache's path,
    missing, when the file has not arrived or did not check out)."""
    if not on_worker_host():
        return file_path
    return verified(sha256) or cache_dir() / "missing"
