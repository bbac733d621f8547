"""The seed's `/printer/` API (Repetier-Server), the host's extras and Repetier's dialect.

Every answer is UTF-8 JSON in the seed's envelope `{"error": "", "data": ...}`, with a
real HTTP status on failure. Three answers leave the envelope because the clients that
call them parse another shape (PrusaSlicer's Repetier host type, `Repetier.cpp`):

- `GET /printer/list` has no `error` key when all is well: PrusaSlicer treats any
  `error` key, even an empty one, as a failure.
- `GET /printer/info` is Repetier-Server's server description (`name`, `software`...).
- `/printer/api/<slug>?a=...` answers in Repetier-Server's own shapes
  (`{"groupNames": [...]}` at the top level).

Seed calls:

- `list`: the printers the caller may view.
- `send/<slug>?cmd=`: queue a command (409 "Printer offline", 404 "Unknown printer").
  `[ESPxxx]` commands are answered to the caller: the worker's reply is awaited
  for a few seconds and returned in `data`.
- `response/<slug>?start=&filter=`: the response log after id `start`; `filter` is
  a bit mask that removes lines of those kinds (1 commands, 2 acks, 4 other
  responses, 8 non-maskable messages).
- `job/<slug>?a=...`: see `job()` below.

Extras a host needs (`state`, `connect`, `disconnect`, `bedclear`, `emergency`,
`queue`) are in `host.py`; Repetier-Server's own calls in `repetier.py`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from asgiref.sync import sync_to_async
from django.conf import settings
from django.db.models import Max
from django.http import HttpRequest, HttpResponse, JsonResponse
from ninja import Router
from ninja.errors import HttpError

from jobs import services
from jobs import uploads as sessions
from jobs.gcode import BadGcode
from jobs.models import ACTIVE_STATES, Job, Upload, running_job
from printers.models import Printer, QueuedCommand, ResponseLine
from printhost import audit
from printhost.access import Caller, Forbidden
from printhost.api.common import caller_of, envelope, printer_for
from printhost.clients import (
    ONLINE_STATES,
    PrinterOffline,
    run_action,
    run_command,
    wait_reply,
)
from printhost.models import Role

if TYPE_CHECKING:
    from django.core.files.uploadedfile import UploadedFile

router = Router(tags=["printer (Repetier-Server)"])

#: Most response lines one `response` call returns; `lastid` says where to go on.
RESPONSE_PAGE = 1000
VERSION = "0.1.0"


# -- shapes -------------------------------------------------------------------------


def job_dict(job: Job) -> dict[str, Any]:
    """One job as the API shows it (the shape websockets use too)."""
    return job.as_dict()


def active_job(printer: Printer) -> Job | None:
    return running_job(printer.pk)


def _job_word(printer: Printer, active: Job | None) -> str:
    """The seed's `job` field: none, printing, paused or waitstart."""
    if printer.state == Printer.State.WAITSTART:
        return "waitstart"
    if active is None:
        return "none"
    return "paused" if active.state == Job.State.PAUSED else "printing"


def printer_entry(printer: Printer) -> dict[str, Any]:
    """The seed's list entry, plus `state` and `active` (enabled)."""
    active = active_job(printer)
    return {
        "name": printer.name,
        "slug": printer.slug,
        "online": 1 if printer.state in ONLINE_STATES else 0,
        "active": printer.enabled,
        "job": _job_word(printer, active),
        "state": printer.state,
    }


def current_job(job: Job | None) -> dict[str, Any] | None:
    """The running job with its elapsed time and ETA."""
    return None if job is None else job.as_dict()


def printer_state(printer: Printer) -> dict[str, Any]:
    """Everything a host shows about a printer at a glance."""
    active = active_job(printer)
    status = printer.machine_status or {}
    queue = Job.objects.filter(printer=printer, state=Job.State.QUEUED)
    return {
        "slug": printer.slug,
        "name": printer.name,
        "state": printer.state,
        "message": printer.state_message,
        "online": printer.state in ONLINE_STATES,
        "waitstart": printer.state == Printer.State.WAITSTART,
        "firmware": printer.firmware,
        "firmware_name": printer.firmware_name,
        "temperatures": printer.temperatures or {},
        "position": {k: v for k, v in status.items() if k != "state"},
        "machine_state": status.get("state", ""),
        "job": current_job(active),
        "queue": [job_dict(job) for job in queue],
    }


# -- helpers ------------------------------------------------------------------------


def request_params(request: HttpRequest) -> dict[str, str]:
    """Query parameters, plus form fields of a form or multipart POST.

    A raw body (an `append` chunk) is never parsed: only form content types are.
    """
    values = {k: request.GET.get(k, "") for k in request.GET}
    content_type = request.content_type or ""
    if request.method == "POST" and content_type in (
        "multipart/form-data",
        "application/x-www-form-urlencoded",
    ):
        for key in request.POST:
            values.setdefault(key, request.POST.get(key, ""))
    return values


def parse_int(value: str | None, name: str, *, default: int, minimum: int = 0) -> int:
    """An integer parameter, or a 400 that says what was wrong."""
    if value in (None, ""):
        return default
    try:
        number = int(value)
    except ValueError:
        raise HttpError(400, f"{name} must be an integer, not {value!r}") from None
    if number < minimum:
        raise HttpError(400, f"{name} must be {minimum} or more, not {number}")
    return number


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


def job_of(printer: Printer, params: dict[str, str]) -> Job:
    job_id = parse_int(params.get("id"), "id", default=-1, minimum=1)
    if job_id < 0:
        raise HttpError(400, "id is required")
    job = Job.objects.filter(printer=printer, pk=job_id).first()
    if job is None:
        raise HttpError(404, f"no job {job_id} on printer {printer.slug!r}")
    return job


def job_action(
    request: HttpRequest, printer: Printer, action: str, audit_name: str
) -> QueuedCommand:
    return run_action(caller_of(request), printer, action, audit_as=audit_name)


# -- seed calls ---------------------------------------------------------------------


@router.get("/printer/list", summary="Printers the caller may view")
def printer_list(request: HttpRequest) -> HttpResponse:
    """The seed's printer list. No `error` key on success (PrusaSlicer needs that)."""
    printers = caller_of(request).printers(Role.VIEWER)
    return JsonResponse({"data": [printer_entry(p) for p in printers]})


@router.api_operation(["GET", "POST"], "/printer/send/{slug}", summary="Send a command")
async def send(request: HttpRequest, slug: str) -> HttpResponse:
    """Queue `cmd` for the printer. `[ESPxxx]` commands wait for the worker's reply.

    Emergencies (M112, M108, M410) skip every queue and are accepted offline too.
    """
    params = request_params(request)
    command = (params.get("cmd") or "").strip()
    printer = await sync_to_async(printer_for)(request, slug, Role.OPERATOR)
    if not command:
        raise HttpError(400, "cmd is required")
    try:
        row = await sync_to_async(run_command)(caller_of(request), printer, command)
    except PrinterOffline as error:
        raise HttpError(409, str(error)) from None
    except ValueError as error:
        raise HttpError(400, str(error)) from None
    if not command.upper().startswith("[ESP"):
        return envelope({"id": row.pk, "kind": row.kind})
    wait = settings.PRINTHOST_ESP_REPLY_SECONDS
    answer = await wait_reply(row.pk, wait)
    if answer is None:
        return envelope(
            {"id": row.pk, "state": "pending"},
            f"no reply from the printer within {wait:g} s; the command stays queued",
            status=504,
        )
    return envelope({"id": row.pk, **answer})


@router.get("/printer/response/{slug}", summary="Response log after an id")
def response(request: HttpRequest, slug: str) -> HttpResponse:
    """Lines with id > `start`, without the kinds whose bits are set in `filter`.

    `lastid` is where to continue: the last line looked at (at most 1000 lines per
    call), else the newest id of the log.
    """
    printer = printer_for(request, slug, Role.VIEWER)
    start = parse_int(request.GET.get("start"), "start", default=0)
    mask = parse_int(request.GET.get("filter"), "filter", default=0)
    if mask > 15:
        raise HttpError(400, f"filter is a sum of 1, 2, 4 and 8 (0..15), not {mask}")
    kinds = [k for k in (1, 2, 4, 8) if not k & mask]
    rows = list(
        ResponseLine.objects.filter(printer=printer, seq__gt=start, kind__in=kinds)
        .order_by("seq")
        .values("seq", "time", "text", "kind")[:RESPONSE_PAGE]
    )
    if len(rows) == RESPONSE_PAGE:
        last = rows[-1]["seq"]
    else:
        newest = ResponseLine.objects.filter(printer=printer).aggregate(m=Max("seq"))
        last = max(start, newest["m"] or 0)
    state = printer_state(printer)
    return envelope(
        {
            "lastid": last,
            "lines": [
                {
                    "id": r["seq"],
                    "time": r["time"].isoformat(),
                    "text": r["text"],
                    "type": r["kind"],
                }
                for r in rows
            ],
            "state": {k: state[k] for k in ("state", "message", "temperatures", "job")},
        }
    )


JOB_ACTIONS = (
    "create",
    "append",
    "finish",
    "upload",
    "start",
    "pause",
    "resume",
    "abort",
    "list",
    "delete",
    "reprint",
)


@router.api_operation(["GET", "POST"], "/printer/job/{slug}", summary="Jobs: a=...")
def job(request: HttpRequest, slug: str) -> HttpResponse:
    """The seed's job call; `a` says what to do.

    - `create` (`name`, optional `size`, `sha256`, `autostart`): open a chunked
      upload; `data.id` names it.
    - `append` (`id`, optional `offset`, `last=1`; the chunk is the raw request body):
      add a chunk. The append that reaches the announced `size` (or carries
      `last=1`) stores the job: queued, or only stored with `autostart=0`.
    - `finish` (`id`): store the job of a chunked upload whose size was not announced.
    - `upload` (multipart: file part `filename` or `file`, optional `name`,
      `autostart`): the whole file at once.
    - `start` (`id`): queue a stored job.
    - `pause`, `resume`, `abort`: act on the running job.
    - `list`: every job of the printer, queue order.
    - `delete` (`id`): remove a job and its file; a running job is refused (409).
    - `reprint` (`id`): queue a finished job's file again.
    """
    # `a` and `id` come from the query for an append: its body is the chunk.
    action = request.GET.get("a") or ""
    params = (
        {k: request.GET.get(k, "") for k in request.GET}
        if action == "append"
        else request_params(request)
    )
    action = action or params.get("a", "")
    if action not in JOB_ACTIONS:
        raise HttpError(
            400, f"a must be one of {', '.join(JOB_ACTIONS)}, not {action!r}"
        )
    if action == "list":
        printer = printer_for(request, slug, Role.VIEWER)
        jobs = Job.objects.filter(printer=printer).order_by("position", "id")
        return envelope([job_dict(j) for j in jobs])
    if action == "upload":
        printer = upload_target(request, slug)
        mode = autostart_mode(params.get("autostart"))
        file = uploaded_file(request)
        stored = store_upload(
            request,
            printer,
            file,
            name=params.get("name", ""),
            queue=should_queue(printer, mode),
            sha256=params.get("sha256", ""),
        )
        return envelope(job_dict(stored))
    if action in ("create", "append", "finish"):
        printer = upload_target(request, slug)
        return _chunked(request, printer, action, params)
    printer = printer_for(request, slug, Role.OPERATOR)
    return _job_control(request, printer, action, params)


def _job_control(
    request: HttpRequest, printer: Printer, action: str, params: dict[str, str]
) -> HttpResponse:
    caller = caller_of(request)
    if action in ("pause", "resume", "abort"):
        active = active_job(printer)
        if active is None:
            raise HttpError(409, f"no job is printing on {printer.slug}")
        if action == "pause" and active.state == Job.State.PAUSED:
            raise HttpError(409, f"job {active.pk} is already paused")
        if action == "resume" and active.state != Job.State.PAUSED:
            raise HttpError(409, f"job {active.pk} is not paused")
        job_action(request, printer, action, f"job.{action}")
        return envelope(job_dict(active))
    target = job_of(printer, params)
    if action == "start":
        if not services.queue_job(target):
            raise HttpError(
                409, f"job {target.pk} is {target.state}, only a stored job can start"
            )
        target.refresh_from_db()
        audit.record(caller, "job.start", printer=printer, job=target)
        return envelope(job_dict(target))
    if action == "delete":
        if target.state in ACTIVE_STATES:
            raise HttpError(
                409, f"job {target.pk} is {target.state}: abort it before deleting it"
            )
        audit.record(
            caller, "job.delete", printer=printer, job=None, detail=str(target)
        )
        services.delete_job_file(target)
        target.delete()
        return envelope({"id": params.get("id"), "deleted": True})
    # reprint
    try:
        again = services.reprint(
            target,
            origin=caller.origin,
            user=caller.user if caller.authenticated else None,
        )
    except BadGcode as error:
        raise HttpError(409, str(error)) from None
    audit.record(caller, "job.reprint", printer=printer, job=again)
    return envelope(job_dict(again))


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


def _chunked(
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
    return envelope({"id": upload.pk, "complete": True, "job": job_dict(job_row)})
