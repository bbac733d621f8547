"""Cancel one object of a running print.

    GET  /printer/objects/<slug>?id=<job>   the job's objects and which are cancelled
                                            (`&ranges=1`: each object's commands,
                                            for the preview to grey cancelled ones)
    POST /printer/objects/<slug>            JSON {"id": <job>, "object": "<name>"}
                                            (or the same as query parameters)

Objects are named as the file's analysis lists them (`analysis.objects`). The POST
validates and writes intent only: the name joins `Job.cancelled_objects` (a
conditional update, so two operators cancelling at once both count) and a
`cancel_object:<job>` request goes to the printer's worker, which sends `M486 P<n>`
when the firmware cancels objects itself and the file numbers them, and otherwise
skips the object's extrusion host-side from the next line it reads
(printers/streaming/objects.py). Lines already sent are in the firmware's buffer
and run.

Refusals change nothing: 404 unknown job or object, 409 the job is not printing,
is printed from the SD card, its file names no objects (or the analysis has not
finished), the object is already cancelled, or it is the last one left (abort the
job instead). Moonraker's `EXCLUDE_OBJECT NAME=` (Klipper's own G-code) is not
offered: Moonraker clients send it as a G-code script to Klipper itself.
"""

from __future__ import annotations

from typing import Any

from django.http import HttpRequest, HttpResponse  # noqa: TC002 (ninja reads view hints)
from ninja import Router
from ninja.errors import HttpError

from jobs.analysing import object_ranges_of
from jobs.models import ACTIVE_STATES, Job
from printers.models import QueuedCommand
from printers.worker.requests import CANCEL_OBJECT
from printhost import audit
from printhost.api.common import (
    caller_of,
    envelope,
    job_on,
    json_body,
    parse_int,
    printer_for,
    request_params,
)
from printhost.models import Role

router = Router(tags=["objects"])


def objects_of(job: Job) -> dict[str, Any]:
    """The job's objects (the analysis' names) and the ones cancelled."""
    return {
        "job": job.pk,
        "state": job.state,
        "objects": job.objects_list(),
        "cancelled": list(job.cancelled_objects or []),
    }


#: Files larger than this get no ranges (reading them would hold the request).
RANGES_MAX_BYTES = 64 << 20


@router.get("/printer/objects/{slug}", summary="A job's objects")
def objects(request: HttpRequest, slug: str) -> HttpResponse:
    """`?id=<job>`: the objects the file's analysis found, each with `cancelled`.

    `&ranges=1` adds `ranges`: per object, its commands' [first, end) indexes, read
    from the file (a file over RANGES_MAX_BYTES, or gone, gets none).
    """
    printer = printer_for(request, slug, Role.VIEWER)
    job = job_on(printer, parse_int(request.GET.get("id"), "id", default=-1))
    data = objects_of(job)
    if request.GET.get("ranges") and data["objects"]:
        data["ranges"] = _ranges(job)
    return envelope(data)


def _ranges(job: Job) -> dict[str, list[list[int]]] | None:
    path = job.path
    if job.on_sd_card or not path.is_file() or job.size_bytes > RANGES_MAX_BYTES:
        return None
    return object_ranges_of(job.sha256, path)


@router.post("/printer/objects/{slug}", summary="Cancel one object of a running job")
def cancel_object(request: HttpRequest, slug: str) -> HttpResponse:
    """JSON `{"id": <job>, "object": "<name>"}`: stop printing that object.

    202 with the job's objects; the worker applies it at the next line it reads.
    """
    printer = printer_for(request, slug, Role.OPERATOR)
    body = {**request_params(request), **json_body(request)}
    value = body.get("id")
    job = job_on(
        printer, parse_int(None if value is None else str(value), "id", default=-1)
    )
    name = body.get("object")
    if not isinstance(name, str) or not name:
        raise HttpError(422, 'send {"id": <job>, "object": "<the object\'s name>"}')
    _check(job, name)
    cancelled = [*job.cancelled_objects, name]
    won = Job.objects.filter(
        pk=job.pk,
        state__in=ACTIVE_STATES,
        cancelled_objects=job.cancelled_objects,
    ).update(cancelled_objects=cancelled)
    if won != 1:
        raise HttpError(409, "the job changed meanwhile: look again and retry")
    caller = caller_of(request)
    QueuedCommand.objects.create(
        printer=printer,
        kind=QueuedCommand.Kind.ACTION,
        text=f"{CANCEL_OBJECT}:{job.pk}",
        origin=caller.origin,
    )
    audit.record(caller, "job.cancel_object", printer=printer, job=job, detail=name)
    job.cancelled_objects = cancelled
    return envelope(objects_of(job), status=202)


def _check(job: Job, name: str) -> None:
    """Why *name* cannot be cancelled in *job* (an HttpError), in the order a user
    would fix it."""
    if job.state not in ACTIVE_STATES:
        raise HttpError(409, f"job {job.pk} is {job.state}, not printing")
    if job.on_sd_card:
        raise HttpError(
            409, "the printer prints this job from its SD card: cancel it there"
        )
    names = job.objects_list()
    if not names:
        raise HttpError(
            409,
            "the file names no objects (slice it with object labels) or its "
            "analysis has not finished",
        )
    if name not in names:
        raise HttpError(
            404, f"no object {name!r} in the file; it has {', '.join(names)}"
        )
    if name in job.cancelled_objects:
        raise HttpError(409, f"{name!r} is already cancelled")
    if len(set(names) - set(job.cancelled_objects)) <= 1:
        raise HttpError(409, f"{name!r} is the last object left: abort the job instead")
