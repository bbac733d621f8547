"""The printer's own SD card: its listing, printing a file from it, copying a job to it.

Printing from the card and copying onto it are jobs in the printer's queue (kinds
`sd_print` and `sd_upload`, see jobs/sdcard.py); listing and deleting are requests
for the worker. GETs only read. The services' refusals map to statuses in
`common.install_error_handlers`: a bad name 422, no card (GRBL) 409.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from django.http import HttpRequest, HttpResponse  # noqa: TC002 (ninja reads view hints)
from ninja import Router
from ninja.errors import HttpError

from jobs import sdcard
from jobs.models import Job
from printhost import audit
from printhost.api.common import caller_of, envelope, json_body, printer_for
from printhost.models import Role

if TYPE_CHECKING:
    from printers.models import Printer

router = Router(tags=["printer's SD card"])


def card_of(printer: Printer) -> dict[str, Any]:
    """The card as the printer last listed it, and whether it can have one."""
    card = dict(printer.sd_card or {})
    return {
        "supported": not printer.is_grbl,
        "present": card.get("present"),
        "files": card.get("files") or [],
        "listed": card.get("listed"),
        "message": card.get("message", ""),
    }


def _name(body: dict[str, Any], key: str = "name", *, required: bool = True) -> str:
    value = body.get(key, "")
    if not isinstance(value, str) or (required and not value.strip()):
        raise HttpError(422, f'send {{"{key}": "<the file\'s name on the card>"}}')
    return sdcard.card_name(value) if value.strip() else ""


@router.get("/printer/sd/{slug}", summary="The printer's SD card")
def card(request: HttpRequest, slug: str) -> HttpResponse:
    """The files on the card as the printer last listed them (M20), with sizes."""
    return envelope(card_of(printer_for(request, slug, Role.VIEWER)))


@router.post("/printer/sd/{slug}/refresh", summary="List the SD card again")
def refresh(request: HttpRequest, slug: str) -> HttpResponse:
    """The worker asks the printer for its listing (M20); 202 with the request id."""
    printer = printer_for(request, slug, Role.OPERATOR)
    row = sdcard.list_sd_card(printer, origin=caller_of(request).origin)
    audit.record(caller_of(request), "sd.list", printer=printer)
    return envelope({"id": row.pk}, status=202)


@router.post("/printer/sd/{slug}/print", summary="Print a file from the SD card")
def print_file(request: HttpRequest, slug: str) -> HttpResponse:
    """JSON `{"name": "PART.GCO"}`: queue a job the printer runs from its card."""
    printer = printer_for(request, slug, Role.OPERATOR)
    name = _name(json_body(request))
    caller = caller_of(request)
    job = sdcard.queue_sd_print(printer, name, origin=caller.origin, user=caller.user)
    audit.record(caller, "sd.print", printer=printer, job=job, detail=name)
    return envelope(job.as_dict(), status=201)


@router.post("/printer/sd/{slug}/upload", summary="Copy a job's file to the SD card")
def upload(request: HttpRequest, slug: str) -> HttpResponse:
    """JSON `{"job": id, "name": "PART.GCO" (optional, 8.3), "print": false}`.

    Queues a job that writes the stored job's file onto the card (M28 ... M29);
    with `print`, a print of it from the card follows once the copy is complete.
    """
    printer = printer_for(request, slug, Role.OPERATOR)
    body = json_body(request)
    job_id, print_after = body.get("job"), body.get("print", False)
    if not isinstance(job_id, int) or isinstance(job_id, bool):
        raise HttpError(422, 'send {"job": <the id of a stored job>}')
    if not isinstance(print_after, bool):
        raise HttpError(422, "print must be true or false")
    name = _name(body, required=False)
    source = Job.objects.filter(pk=job_id, printer=printer).first()
    if source is None:
        raise HttpError(404, f"no job {job_id} on {printer.slug}")
    caller = caller_of(request)
    job = sdcard.queue_sd_upload(
        printer,
        source,
        sd_name=name,
        print_after=print_after,
        origin=caller.origin,
        user=caller.user,
    )
    audit.record(caller, "sd.upload", printer=printer, job=job, detail=job.sd_name)
    return envelope(job.as_dict(), status=201)


@router.post("/printer/sd/{slug}/delete", summary="Delete a file from the SD card")
def delete(request: HttpRequest, slug: str) -> HttpResponse:
    """JSON `{"name": "PART.GCO"}`: the worker sends M30 and lists the card again."""
    printer = printer_for(request, slug, Role.OPERATOR)
    name = _name(json_body(request))
    caller = caller_of(request)
    row = sdcard.delete_sd_file(printer, name, origin=caller.origin)
    audit.record(caller, "sd.delete", printer=printer, detail=name)
    return envelope({"id": row.pk}, status=202)
