"""Resumable uploads (printhost's own, in the spirit of tus): big files in pieces.

1. `POST /printer/upload/<slug>` with `name`, `size`, optional `sha256` and
   `autostart` (1 queue, 0 store, -1 queue if the queue is empty) opens a session:
   `{"id": ..., "offset": 0}`.
2. `PATCH /printer/upload/<slug>/<id>` with header `Upload-Offset: <n>` and raw bytes
   as the body appends them. A wrong offset is a 409 that gives the right one; bytes
   past the announced size are a 413. The answer carries the new offset; the PATCH
   that completes the file stores the job and returns it.
3. After a dropped connection, `HEAD` or `GET /printer/upload/<slug>/<id>` gives the
   offset (also as the `Upload-Offset` header): continue from there.
4. `DELETE` abandons a session. Sessions untouched for a day are removed.

Why pieces: a connection that drops after 900 MB of a 1 GB file should not cost the
whole file again. Each PATCH body is read with `request.read()` in chunks and appended
to the partial file, never loaded whole (and `printhost.serve` keeps request bodies on
disk while they wait for Django, so neither form costs the file's size in memory).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ninja import Router
from ninja.errors import HttpError

from jobs import uploads as sessions
from printhost.api.common import (
    caller_of,
    envelope,
    parse_int,
    printer_for,
    request_params,
)
from printhost.api.storing import (
    autostart_mode,
    finish_session,
    session_dict,
    upload_of,
    upload_target,
)
from printhost.models import Role

if TYPE_CHECKING:
    from django.http import HttpRequest, HttpResponse

router = Router(tags=["resumable uploads"])


def _with_offset(response: HttpResponse, offset: int) -> HttpResponse:
    response["Upload-Offset"] = str(offset)
    response["Cache-Control"] = "no-store"
    return response


@router.post("/printer/upload/{slug}", summary="Open a resumable upload")
def open_session(request: HttpRequest, slug: str) -> HttpResponse:
    """Start a session for `name` of `size` bytes (query or form fields)."""
    params = request_params(request)
    printer = upload_target(request, slug)
    name = params.get("name", "")
    if not name:
        raise HttpError(400, "name is required")
    size = parse_int(params.get("size"), "size", default=-1, minimum=1)
    if size < 0:
        raise HttpError(400, "size is required (the file's length in bytes)")
    caller = caller_of(request)
    upload = sessions.open_upload(
        printer,
        name,
        size=size,
        sha256=params.get("sha256", ""),
        user=caller.user if caller.authenticated else None,
        options={"autostart": autostart_mode(params.get("autostart"))},
    )
    response = envelope(session_dict(upload), status=201)
    response["Location"] = f"/printer/upload/{printer.slug}/{upload.pk}"
    return _with_offset(response, 0)


@router.api_operation(
    ["GET", "HEAD"], "/printer/upload/{slug}/{upload_id}", summary="Upload offset"
)
def offset(request: HttpRequest, slug: str, upload_id: str) -> HttpResponse:
    """Where to continue: the bytes the server really has."""
    printer = printer_for(request, slug, Role.OPERATOR)
    upload = upload_of(printer, caller_of(request), upload_id)
    return _with_offset(envelope(session_dict(upload)), sessions.offset_of(upload))


@router.patch("/printer/upload/{slug}/{upload_id}", summary="Append bytes")
def patch(request: HttpRequest, slug: str, upload_id: str) -> HttpResponse:
    """Append the raw body at `Upload-Offset`; the completing PATCH stores the job."""
    printer = printer_for(request, slug, Role.OPERATOR)
    upload = upload_of(printer, caller_of(request), upload_id)
    header = request.headers.get("Upload-Offset")
    if header is None:
        raise HttpError(400, "the Upload-Offset header is required")
    at = parse_int(header, "Upload-Offset", default=0)
    length = request.headers.get("Content-Length")
    try:
        now = sessions.append(
            upload,
            request.read,
            offset=at,
            length=parse_int(length, "Content-Length", default=0) if length else None,
        )
    except sessions.OffsetMismatch as error:
        return _with_offset(
            envelope({"offset": error.expected}, str(error), status=409),
            error.expected,
        )
    if not sessions.is_complete(upload):
        return _with_offset(envelope({**session_dict(upload), "complete": False}), now)
    job = finish_session(request, upload)
    return _with_offset(
        envelope(
            {"id": upload.pk, "offset": now, "complete": True, "job": job.as_dict()}
        ),
        now,
    )


@router.delete("/printer/upload/{slug}/{upload_id}", summary="Abandon an upload")
def abandon(request: HttpRequest, slug: str, upload_id: str) -> HttpResponse:
    printer = printer_for(request, slug, Role.OPERATOR)
    upload = upload_of(printer, caller_of(request), upload_id)
    sessions.discard(upload)
    return envelope({"id": upload_id, "deleted": True})
