"""How uploads become jobs, for every upload path of the seed API and its dialects.

Which printer an upload goes to (`upload_target`), multipart files (`store_upload`),
the seed's chunked `create` / `append` (`chunked_upload`) and the resumable sessions
(`upload_of`, `finish_session`) all end in `jobs.services`: checked, stored, queued
or only stored per `autostart`, and audited.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ninja.errors import HttpError

from jobs import services
from jobs import uploads as sessions
from jobs.models import Job, Upload
from printhost import audit
from printhost.access import Caller, Forbidden
from printhost.api.common import (
    caller_of,
    envelope,
    parse_int,
    printer_for,
)
from printhost.models import Role

if TYPE_CHECKING:
    from django.core.files.uploadedfile import UploadedFile
    from django.http import HttpRequest, HttpResponse

    from printers.models import Printer


def autostart_mode(value: str | None, *, default: str = "1") -> str:
    """Repetier's autostart: `1`/`true` queue, `0`/`false` store, `-1` queue if empty."""
    word = (value or default).strip().lower()
    if word in ("1", "true", "yes", "on"):
        return "queue"
    if word in ("0", "false", "no", "off"):
        return "store"
    if word == "-1":
        return "if_empty"
    raise HttpError(400, f"autostart must be 1, 0, -1, true or false, not {value!r}")


def should_queue(printer: Printer, mode: str) -> bool:
    """Whether an upload with autostart *mode* joins the queue or is only stored."""
    if mode == "if_empty":
        return services.queue_is_empty(printer)
    return mode == "queue"


def upload_target(request: HttpRequest, slug: str) -> Printer:
    """Where an upload goes: the key's printer, else *slug*, else the user's default.

    A key bound to one printer uploads there when the URL names no printer (`-` or
    `default`) and is refused (403) when the URL names another one: a job never
    lands silently on a machine other than the one the URL says.
    """
    caller = caller_of(request)
    if slug not in ("", "-", "default"):
        return printer_for(request, slug, Role.OPERATOR)
    if caller.key is not None and caller.key.printer_id is not None:
        printer = caller.key.printer
    else:
        printer = caller.default_printer()
        if printer is None:
            raise HttpError(
                404, "no default printer: name one in the URL or set a default"
            )
    caller.require(printer, Role.OPERATOR)
    return printer


def store_upload(
    request: HttpRequest,
    printer: Printer,
    file: UploadedFile,
    *,
    name: str,
    queue: bool,
    sha256: str = "",
) -> Job:
    """Store a multipart upload as a job (queued or only stored) and audit it."""
    caller = caller_of(request)
    job = services.enqueue_upload(
        printer,
        file,
        name=name or file.name or "upload.gcode",
        origin=caller.origin,
        user=caller.user if caller.authenticated else None,
        queue=queue,
        sha256=sha256,
    )
    audit.record(
        caller,
        "job.upload",
        printer=printer,
        job=job,
        detail=f"{job.name} {job.size_bytes} bytes, {'queued' if queue else 'stored'}",
    )
    return job


def uploaded_file(request: HttpRequest) -> UploadedFile:
    """The file part of a multipart upload: `filename` (Repetier) or `file`."""
    file = request.FILES.get("filename") or request.FILES.get("file")
    if file is None:
        raise HttpError(
            400, "no file: send multipart/form-data with a file part named 'filename'"
        )
    return file


def upload_of(printer: Printer, caller: Caller, upload_id: str) -> Upload:
    upload = Upload.objects.filter(pk=upload_id, printer=printer).first()
    if upload is None:
        raise HttpError(404, f"no upload {upload_id!r} on printer {printer.slug!r}")
    if upload.user_id is not None and upload.user_id != getattr(
        caller.user, "pk", None
    ):
        raise Forbidden("this upload belongs to another user")
    return upload


def session_dict(upload: Upload) -> dict[str, Any]:
    """An upload session as the API shows it."""
    return {
        "id": upload.pk,
        "name": upload.name,
        "size": upload.size,
        "offset": sessions.offset_of(upload),
        "sha256": upload.sha256_expected,
    }


def finish_session(request: HttpRequest, upload: Upload) -> Job:
    """Store a complete session's file as a job and audit it."""
    caller = caller_of(request)
    printer = upload.printer
    mode = upload.options.get("autostart", "queue")
    job = sessions.finish(
        upload, origin=caller.origin, queue=should_queue(printer, mode)
    )
    audit.record(
        caller,
        "job.upload",
        printer=printer,
        job=job,
        detail=f"{job.name} {job.size_bytes} bytes in chunks, {job.state}",
    )
    return job


def chunked_upload(
    request: HttpRequest, printer: Printer, action: str, params: dict[str, str]
) -> HttpResponse:
    caller = caller_of(request)
    if action == "create":
        name = params.get("name", "")
        if not name:
            raise HttpError(400, "name is required")
        upload = sessions.open_upload(
            printer,
            name,
            size=parse_int(params.get("size"), "size", default=0),
            sha256=params.get("sha256", ""),
            user=caller.user if caller.authenticated else None,
            options={"autostart": autostart_mode(params.get("autostart"))},
        )
        return envelope(session_dict(upload))
    upload_id = params.get("id", "")
    if not upload_id:
        raise HttpError(400, "id is required (the id `create` returned)")
    upload = upload_of(printer, caller, upload_id)
    if action == "append":
        offset = params.get("offset")
        try:
            sessions.append(
                upload,
                request.read,
                offset=None
                if offset in (None, "")
                else parse_int(offset, "offset", default=0),
            )
        except sessions.OffsetMismatch as error:
            return envelope({"offset": error.expected}, str(error), status=409)
        last = params.get("last", "").lower() in ("1", "true", "yes")
        if not (last or sessions.is_complete(upload)):
            return envelope({**session_dict(upload), "complete": False})
    job_row = finish_session(request, upload)
    return envelope({"id": upload.pk, "complete": True, "job": job_row.as_dict()})
