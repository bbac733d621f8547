"""What a host needs beyond the seed: state, connect, disconnect, bed clear, emergency
stop and reordering the queue."""

from __future__ import annotations

import json

from django.http import HttpRequest, HttpResponse  # noqa: TC002 (ninja reads view hints)
from ninja import Router
from ninja.errors import HttpError

from jobs import services
from jobs.models import Job
from printers.models import Printer, QueuedCommand
from printhost import audit
from printhost.api.common import caller_of, envelope, printer_for
from printhost.api.shapes import STATE_FIELDS, printer_state
from printhost.clients import run_action
from printhost.models import Role

router = Router(tags=["printer (host extras)"])


@router.get("/printer/state/{slug}", summary="Printer state, job, queue")
def state(request: HttpRequest, slug: str) -> HttpResponse:
    """State, temperatures, position, the running job with progress and ETA, the queue."""
    printer = printer_for(request, slug, Role.VIEWER, fields=STATE_FIELDS)
    return envelope(printer_state(printer))


@router.post("/printer/connect/{slug}", summary="Connect (or reconnect) the printer")
def connect(request: HttpRequest, slug: str) -> HttpResponse:
    printer = printer_for(request, slug, Role.OPERATOR)
    row = run_action(
        caller_of(request), printer, QueuedCommand.Action.RECONNECT, audit_as="connect"
    )
    return envelope({"id": row.pk})


@router.post("/printer/disconnect/{slug}", summary="Close the printer's port")
def disconnect(request: HttpRequest, slug: str) -> HttpResponse:
    printer = printer_for(request, slug, Role.OPERATOR)
    row = run_action(
        caller_of(request),
        printer,
        QueuedCommand.Action.DISCONNECT,
        audit_as="disconnect",
    )
    return envelope({"id": row.pk})


@router.post("/printer/bedclear/{slug}", summary="Confirm the bed is clear")
def bedclear(request: HttpRequest, slug: str) -> HttpResponse:
    """Leave `waitstart`: the next queued job may start (409 if not waiting)."""
    printer = printer_for(request, slug, Role.OPERATOR)
    if printer.state != Printer.State.WAITSTART:
        raise HttpError(409, f"{printer.slug} is {printer.state}, not waiting for it")
    row = run_action(
        caller_of(request),
        printer,
        QueuedCommand.Action.BED_CLEAR,
        audit_as="bed_clear",
    )
    return envelope({"id": row.pk})


@router.post("/printer/emergency/{slug}", summary="Emergency stop")
def emergency(request: HttpRequest, slug: str) -> HttpResponse:
    """M112 (Marlin) or feed hold + reset (GRBL), ahead of everything queued."""
    printer = printer_for(request, slug, Role.OPERATOR)
    row = run_action(
        caller_of(request), printer, "emergency_stop", audit_as="emergency"
    )
    return envelope({"id": row.pk})


@router.post("/printer/prompt/{slug}", summary="Answer the printer's prompt")
def prompt(request: HttpRequest, slug: str) -> HttpResponse:
    """JSON `{"choice": n}`: button n (from 0) of the prompt the printer shows.

    Sent as `M876 S<n>` through the firmware's emergency parser (it reaches a
    printer parked in M600). 409 if nothing is asked, 422 for a button it lacks.
    """
    printer = printer_for(request, slug, Role.OPERATOR)
    try:
        body = json.loads(request.body or b"{}")
    except ValueError:
        raise HttpError(400, "the body must be JSON") from None
    choice = body.get("choice") if isinstance(body, dict) else None
    if not isinstance(choice, int) or isinstance(choice, bool):
        raise HttpError(422, 'send {"choice": n}, n the button\'s index from 0')
    shown = (printer.machine_status or {}).get("prompt")
    if not shown:
        raise HttpError(409, f"{printer.slug} is not asking anything now")
    buttons = max(1, len(shown.get("choices") or ()))
    if not 0 <= choice < buttons:
        raise HttpError(
            422, f"choice {choice} is not one of the {buttons} the printer offers"
        )
    labels = shown.get("choices") or ["(no button)"]
    row = run_action(
        caller_of(request),
        printer,
        f"{QueuedCommand.Action.PROMPT}:{choice}",
        audit_as="prompt",
        detail=f"{shown.get('message', '')}: {labels[choice]}",
    )
    return envelope({"id": row.pk, "answerable": bool(shown.get("answerable"))})


@router.post("/printer/queue/{slug}", summary="Reorder the queue")
def queue(request: HttpRequest, slug: str) -> HttpResponse:
    """JSON `{"order": [job ids]}` (those first, in order) or `{"id": n, "position": i}`.

    `position` counts from 0 = the head of the queue. Only queued jobs move.
    """
    printer = printer_for(request, slug, Role.OPERATOR)
    try:
        body = json.loads(request.body or b"{}")
    except ValueError:
        raise HttpError(400, "the body must be JSON") from None
    if not isinstance(body, dict):
        raise HttpError(400, 'send {"order": [ids]} or {"id": n, "position": i}')
    queued = list(
        Job.objects.filter(printer=printer, state=Job.State.QUEUED)
        .order_by("position", "id")
        .values_list("pk", flat=True)
    )
    if "order" in body:
        order = body["order"]
        if not isinstance(order, list) or not all(
            isinstance(i, int) and not isinstance(i, bool) for i in order
        ):
            raise HttpError(400, "order must be a list of job ids")
    elif "id" in body and "position" in body:
        job_id, position = body["id"], body["position"]
        if not all(
            isinstance(v, int) and not isinstance(v, bool) for v in (job_id, position)
        ):
            raise HttpError(400, "id and position must be integers")
        if job_id not in queued:
            raise HttpError(409, f"job {job_id} is not queued on {printer.slug}")
        if position < 0:
            raise HttpError(400, "position must be 0 or more")
        order = [i for i in queued if i != job_id]
        order.insert(min(position, len(order)), job_id)
    else:
        raise HttpError(400, 'send {"order": [ids]} or {"id": n, "position": i}')
    try:
        jobs = services.reorder_queue(printer, order)
    except ValueError as error:
        raise HttpError(409, str(error)) from None
    audit.record(
        caller_of(request),
        "queue.reorder",
        printer=printer,
        detail=",".join(str(j.pk) for j in jobs),
    )
    return envelope([j.as_dict() for j in jobs])
