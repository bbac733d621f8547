"""Job files for worker hosts: `GET /host/files/<job id>`, with the host's own key.

A worker host has no share of the control plane's disk; its fetcher
(`printers/fetcher.py`) downloads each job its printers will print. Only the host
that drives the job's printer may read the file (`Authorization: Bearer <host
key>`); anyone else learns nothing about the job (401 without a host key, 404 for
a job that is not the host's). `Range: bytes=N-` continues a download a blink
of the network cut short. The file's SHA-256 goes in `X-Printhost-Sha256`; the
host checks it before printing.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

from django.conf import settings
from django.http import FileResponse, HttpRequest, HttpResponse, JsonResponse
from django.views.decorators.http import require_GET

from jobs.models import HOST_FILE_STATES, Job
from jobs.paths import PathRefused, inside
from printers.hosts import KEY_PREFIX_CHARS, WorkerHost

logger = logging.getLogger("printhost.hostfiles")

_KEY_HEAD = "ph_host_"
_RANGE = re.compile(r"bytes=(\d+)-$")
#: A Range start of more digits is past any file (and int() of thousands raises).
_MOST_DIGITS = 18


def _refuse(status: int, error: str) -> JsonResponse:
    return JsonResponse({"error": error, "data": None}, status=status)


def host_of(request: HttpRequest) -> WorkerHost | None:
    """The enabled worker host whose key the request carries, or None."""
    scheme, _, key = request.headers.get("Authorization", "").partition(" ")
    key = key.strip()
    if scheme.lower() != "bearer" or not key.startswith(_KEY_HEAD):
        return None
    prefix = key[: len(_KEY_HEAD) + KEY_PREFIX_CHARS]
    host = WorkerHost.objects.filter(key_prefix=prefix).first()
    if host is None or not host.key_matches(key):
        return None
    return host


@require_GET
def job_file(request: HttpRequest, job_id: int) -> HttpResponse:
    host = host_of(request)
    if host is None:
        return _refuse(401, "a worker host's key is required (Authorization: Bearer)")
    if not host.enabled:
        return _refuse(403, f"worker host {host.name} is disabled")
    # Only jobs the host will print or is printing (the fetcher asks for no
    # other): not the files of jobs that ended, some perhaps printed while the
    # printer belonged to another host.
    job = (
        Job.objects.filter(
            pk=job_id, printer__worker_host=host, state__in=HOST_FILE_STATES
        )
        .exclude(file="")
        .first()
    )
    if job is None:
        return _refuse(404, f"worker host {host.name} prints no job {job_id}")
    try:
        path = inside(Path(settings.JOB_STORAGE_DIR), job.file)
        file = path.open("rb")
    except (PathRefused, OSError) as error:
        logger.warning("job %s's file for host %s: %s", job_id, host.name, error)
        return _refuse(410, f"job {job_id}'s file is no longer stored")
    size = path.stat().st_size
    start = _range_start(request.headers.get("Range", ""))
    if start is not None and start >= size:
        file.close()
        response = _refuse(416, f"the file has {size} bytes")
        response["Content-Range"] = f"bytes */{size}"
        return response
    if start:
        file.seek(start)
    response = FileResponse(file, content_type="application/octet-stream")
    response["Content-Length"] = str(size - (start or 0))
    response["X-Printhost-Sha256"] = job.sha256
    response["Accept-Ranges"] = "bytes"
    if start is not None:
        response.status_code = 206
        response["Content-Range"] = f"bytes {start}-{size - 1}/{size}"
    logger.info(
        "worker host %s fetches job %s (%d bytes from %d)",
        host.name,
        job_id,
        size,
        start or 0,
    )
    return response


def _range_start(header: str) -> int | None:
    """The start of `bytes=N-` (the one range a resumed download asks for)."""
    match = _RANGE.match(header.strip())
    if match is None:
        return None
    digits = match.group(1)
    return int(digits) if len(digits) <= _MOST_DIGITS else 10**_MOST_DIGITS
