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

from asgiref.sync import sync_to_async
from django.conf import settings
from django.db.models import Max
from django.http import HttpRequest, HttpResponse, JsonResponse
from ninja import Router
from ninja.errors import HttpError

from jobs import services
from jobs.gcode import BadGcode
from jobs.listing import printer_jobs
from jobs.models import ACTIVE_STATES, Job, running_job
from printers.models import Printer, ResponseLine
from printhost import audit
from printhost.api import farm
from printhost.api.common import (
    caller_of,
    envelope,
    finished_asked,
    job_of,
    parse_int,
    printer_for,
    refuse_acting_get,
    request_params,
)
from printhost.api.shapes import ENTRY_FIELDS, printer_entries, printer_state
from printhost.api.storing import (
    autostart_mode,
    chunked_upload,
    should_queue,
    store_upload,
    upload_target,
    uploaded_file,
)
from printhost.clients import (
    PrinterOffline,
    run_action,
    run_command,
    wait_reply,
)
from printhost.models import Role

router = Router(tags=["printer (Repetier-Server)"])

#: Most response lines one `response` call returns; `lastid` says where to go on.
RESPONSE_PAGE = 1000


# -- seed calls ---------------------------------------------------------------------


@router.get("/printer/list", summary="Printers the caller may view")
def printer_list(request: HttpRequest) -> HttpResponse:
    """The seed's printer list. No `error` key on success (PrusaSlicer needs that)."""
    printers = caller_of(request).printers(Role.VIEWER, fields=ENTRY_FIELDS)
    return JsonResponse({"data": printer_entries(printers)})


@router.api_operation(["GET", "POST"], "/printer/send/{slug}", summary="Send a command")
async def send(request: HttpRequest, slug: str) -> HttpResponse:
    """Queue `cmd` for the printer. `[ESPxxx]` commands wait for the worker's reply.

    Emergencies (M112, M108, M410) skip every queue and are accepted offline too.
    """
    params = request_params(request)
    command = (params.get("cmd") or "").strip(" \t\r\n")
    printer = await sync_to_async(printer_for)(request, slug, Role.OPERATOR)
    await sync_to_async(refuse_acting_get)(request, "send")
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
    - `list` (optional `finished`, default 50, at most 500): the printer's open
      jobs in queue order, then its newest finished ones (`jobs/listing.py`).
    - `delete` (`id`): remove a job and its file; a running job is refused (409).
    - `reprint` (`id`): queue a finished job's file again (410 once the upkeep
      removed the file, past the printer's `job_file_days`).
    """
    # `a` and `id` come from the query for an append: its body is the chunk.
    action = request.GET.get("a") or ""
    # An upload: who may send it, and where to, before its body is read.
    target = None
    if request.content_type == "multipart/form-data" and action in ("", "upload"):
        if farm.is_farm(slug):
            farm.farm_caller(request, Role.OPERATOR)
        else:
            target = upload_target(request, slug)
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
    if farm.is_farm(slug):
        return _farm_job_call(request, action, params)
    if action == "list":
        printer = printer_for(request, slug, Role.VIEWER)
        jobs = printer_jobs(printer, finished=finished_asked(params))
        return envelope([j.as_dict() for j in jobs])
    refuse_acting_get(request, f"job a={action}")
    if action == "upload":
        printer = target or upload_target(request, slug)
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
        return envelope(stored.as_dict())
    if action in ("create", "append", "finish"):
        printer = upload_target(request, slug)
        return chunked_upload(request, printer, action, params)
    printer = printer_for(request, slug, Role.OPERATOR)
    return _job_control(request, printer, action, params)


def _farm_job_call(
    request: HttpRequest, action: str, params: dict[str, str]
) -> HttpResponse:
    """`/printer/job/farm`: `a=upload` queues the file for the farm (requirements
    as form fields or query parameters); `a=list` is the farm queue."""
    if action == "list":
        farm.farm_caller(request, Role.VIEWER)
        return envelope(farm.queue_entries())
    if action != "upload":
        raise HttpError(
            400,
            f"the farm takes a=upload (the whole file, multipart) and a=list, not "
            f"a={action}: act on a farm job with /printer/farm/<id>",
        )
    refuse_acting_get(request, "job a=upload")
    stored = farm.store_farm_request(
        request, uploaded_file(request), name=params.get("name", "")
    )
    return envelope(stored.as_dict())


def _job_control(
    request: HttpRequest, printer: Printer, action: str, params: dict[str, str]
) -> HttpResponse:
    caller = caller_of(request)
    if action in ("pause", "resume", "abort"):
        active = running_job(printer.pk)
        if active is None:
            raise HttpError(409, f"no job is printing on {printer.slug}")
        if action == "pause" and active.state == Job.State.PAUSED:
            raise HttpError(409, f"job {active.pk} is already paused")
        if action == "resume" and active.state != Job.State.PAUSED:
            raise HttpError(409, f"job {active.pk} is not paused")
        run_action(caller_of(request), printer, action, audit_as=f"job.{action}")
        return envelope(active.as_dict())
    target = job_of(printer, params)
    if action == "start":
        if not services.queue_job(target):
            raise HttpError(
                409, f"job {target.pk} is {target.state}, only a stored job can start"
            )
        target.refresh_from_db()
        audit.record(caller, "job.start", printer=printer, job=target)
        return envelope(target.as_dict())
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
    except services.FileRemoved as error:
        raise HttpError(410, str(error)) from None
    except BadGcode as error:
        raise HttpError(409, str(error)) from None
    audit.record(caller, "job.reprint", printer=printer, job=again)
    return envelope(again.as_dict())
