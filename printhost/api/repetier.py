"""Repetier-Server's own calls, as PrusaSlicer's and Cura's Repetier host types make them.

These answer in Repetier-Server's shapes, not the seed's envelope: `/printer/info` is
its server description, `/printer/api/<slug>?a=...` answers `{"groupNames": [...]}` and
the like at the top level, and `/printer/model/<slug>` stores an upload unqueued.
"""

from __future__ import annotations

import json
from typing import Any

from django.http import HttpRequest, HttpResponse, JsonResponse
from ninja import Router
from ninja.errors import HttpError

from jobs.listing import printer_jobs
from jobs.models import Job, running_job
from printers.models import Printer, QueuedCommand
from printhost import __version__
from printhost.api.common import (
    caller_of,
    envelope,
    finished_asked,
    printer_for,
    refuse_acting_get,
    request_params,
)
from printhost.api.shapes import printer_entries
from printhost.api.storing import store_upload, upload_target, uploaded_file
from printhost.clients import PrinterOffline, run_action, run_command
from printhost.models import Role

router = Router(tags=["printer (Repetier-Server dialect)"])


@router.get("/printer/info", summary="Server description (Repetier-Server's)")
def printer_info(request: HttpRequest) -> HttpResponse:
    """What Repetier clients test a connection with; `name` starts with "Repetier"."""
    caller = caller_of(request)
    printers = [
        {k: entry[k] for k in ("slug", "name", "online", "active", "job")}
        for entry in printer_entries(caller.printers(Role.VIEWER))
    ]
    return JsonResponse(
        {
            "name": "Repetier-Server compatible printhost",
            "software": "Repetier-Server",
            "version": __version__,
            "variant": "printhost",
            "servername": "printhost",
            "serveruuid": "",
            "apikey": "",
            "printers": printers,
        }
    )


@router.post("/printer/model/{slug}", summary="Upload a model (stored, not queued)")
def model_upload(request: HttpRequest, slug: str) -> HttpResponse:
    """PrusaSlicer's "upload": multipart `a=upload`, file part `filename`, `group`."""
    printer = upload_target(request, slug)  # before the body is read
    params = request_params(request)
    if params.get("a", "upload") != "upload":
        raise HttpError(400, f"a must be upload, not {params.get('a')!r}")
    stored = store_upload(
        request,
        printer,
        uploaded_file(request),
        name=params.get("name", ""),
        queue=False,
    )
    return envelope(stored.as_dict())


def _temps(printer: Printer) -> dict[str, Any]:
    extruders, beds = [], []
    for key, reading in sorted((printer.temperatures or {}).items()):
        entry = {
            "tempRead": reading.get("current", 0),
            "tempSet": reading.get("target", 0),
            "output": 0,
        }
        if key.upper().startswith("B"):
            beds.append(entry)
        elif key.upper().startswith("T"):
            extruders.append(entry)
    return {"extruder": extruders, "heatedBeds": beds, "numExtruder": len(extruders)}


def _list_printer_entry(printer: Printer) -> dict[str, Any]:
    active = running_job(printer.pk)
    (entry,) = printer_entries([printer])
    elapsed = (active.elapsed_seconds() if active else None) or 0
    return {
        **entry,
        "job": active.name if active else "none",
        "jobid": active.pk if active else 0,
        "done": round(active.progress * 100, 2) if active else 0,
        "paused": bool(active and active.state == Job.State.PAUSED),
        "printTime": 0,
        "printedTimeComp": round(elapsed, 1),
        "start": int(active.started_at.timestamp())
        if active and active.started_at
        else 0,
    }


REPETIER_CALLS = (
    "listModelGroups",
    "listPrinter",
    "stateList",
    "send",
    "continueJob",
    "stopJob",
    "listJobs",
    "getPrinterConfig",
)


@router.api_operation(
    ["GET", "POST"], "/printer/api/{slug}", summary="Repetier-Server calls: a=..."
)
def repetier_api(request: HttpRequest, slug: str) -> HttpResponse:
    """Repetier-Server's `api` call in its own answer shapes.

    `a` and `data` (a JSON object) come from the query or a form / multipart body
    (PrusaSlicer posts `a=listModelGroups` as a multipart form).
    """
    params = request_params(request)
    call = params.get("a", "")
    if call not in REPETIER_CALLS:
        raise HttpError(
            400, f"a must be one of {', '.join(REPETIER_CALLS)}, not {call!r}"
        )
    try:
        data = json.loads(params.get("data") or "{}")
    except ValueError:
        raise HttpError(400, "data must be a JSON object") from None
    if not isinstance(data, dict):
        raise HttpError(400, "data must be a JSON object")
    caller = caller_of(request)
    if call == "listModelGroups":
        printer_for(request, slug, Role.VIEWER)
        return JsonResponse({"groupNames": ["#"], "ok": True})
    if call == "listPrinter":
        printer_for(request, slug, Role.VIEWER)
        return JsonResponse(
            [_list_printer_entry(p) for p in caller.printers(Role.VIEWER)], safe=False
        )
    if call == "stateList":
        printer_for(request, slug, Role.VIEWER)
        answer = {}
        for p in caller.printers(Role.VIEWER):
            status = p.machine_status or {}
            answer[p.slug] = {
                **_temps(p),
                **{k: status.get(k) for k in ("x", "y", "z") if k in status},
            }
        return JsonResponse(answer)
    if call == "listJobs":
        printer = printer_for(request, slug, Role.VIEWER)
        jobs = printer_jobs(printer, finished=finished_asked(data))
        return JsonResponse({"data": [j.as_dict() for j in jobs]})
    if call == "getPrinterConfig":
        printer = printer_for(request, slug, Role.VIEWER)
        temps = _temps(printer)
        return JsonResponse(
            {
                "general": {
                    "name": printer.name,
                    "slug": printer.slug,
                    "firmwareName": printer.firmware_name
                    or printer.get_firmware_display(),
                    "baudrate": printer.baud,
                    "device": printer.port,
                },
                "extruders": [{"num": i} for i in range(temps["numExtruder"])],
                "heatedBed": bool(temps["heatedBeds"]),
            }
        )
    printer = printer_for(request, slug, Role.OPERATOR)
    refuse_acting_get(request, f"a={call}")
    if call == "send":
        command = str(data.get("cmd", "")).strip()
        if not command:
            raise HttpError(400, 'send needs data={"cmd": "..."}')
        try:
            run_command(caller, printer, command)
        except PrinterOffline as error:
            raise HttpError(409, str(error)) from None
        except ValueError as error:
            raise HttpError(400, str(error)) from None
        return JsonResponse({})
    active = running_job(printer.pk)
    if active is None:
        raise HttpError(409, f"no job is printing on {printer.slug}")
    if call == "continueJob":
        run_action(
            caller_of(request),
            printer,
            QueuedCommand.Action.RESUME,
            audit_as="job.resume",
        )
    else:  # stopJob
        run_action(
            caller_of(request),
            printer,
            QueuedCommand.Action.ABORT,
            audit_as="job.abort",
        )
    return JsonResponse({})
