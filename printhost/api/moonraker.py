"""Moonraker's API, as far as slicers use it (PrusaSlicer's and OrcaSlicer's
"Moonraker" host types, Cura2Moonraker): server info, upload (+ print), job control.

Answers are wrapped in `{"result": ...}` except the upload's, as Moonraker does;
errors use Moonraker's `{"error": {"code", "message"}}`. Every path is also served
under `/p/<slug>/`. A busy printer queues an upload that asks to print.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Any

from django.http import HttpRequest, HttpResponse, JsonResponse
from ninja import Router
from ninja.errors import HttpError

from jobs.gcode import BadGcode
from jobs.models import Job, running_job
from jobs.services import ChecksumMismatch, FileRemoved
from printers.models import Printer
from printhost.access import Forbidden, NotAuthenticated
from printhost.api.analysis import serve_thumbnail
from printhost.api.common import caller_of
from printhost.api.dialects import (
    choose_printer,
    dialect_route,
    find_job,
    print_job,
    stored_name,
    truthy,
    upload_from_form,
)
from printhost.api.farm import farm_caller, is_farm, store_farm_request
from printhost.clients import run_action
from printhost.models import Role

if TYPE_CHECKING:
    from collections.abc import Callable

router = Router(tags=["Moonraker dialect"])

MOONRAKER_VERSION = "v0.9.3-printhost"


def _error(status: int, message: str) -> JsonResponse:
    return JsonResponse({"error": {"code": status, "message": message}}, status=status)


def moonraker_errors(view: Callable[..., HttpResponse]) -> Callable[..., HttpResponse]:
    """Answer the view's errors in Moonraker's shape (auth before the view stays 401)."""

    @functools.wraps(view)
    def wrapped(request: HttpRequest, *args: Any, **kwargs: Any) -> HttpResponse:
        try:
            return view(request, *args, **kwargs)
        except HttpError as error:
            return _error(error.status_code, str(error))
        except NotAuthenticated as error:
            return _error(401, str(error))
        except Forbidden as error:
            return _error(403, str(error) or "not allowed")
        except ChecksumMismatch as error:
            return _error(422, str(error))
        except FileRemoved as error:
            return _error(410, str(error))
        except BadGcode as error:
            return _error(413 if "over the limit" in str(error) else 400, str(error))

    return wrapped


def _ok() -> JsonResponse:
    return JsonResponse({"result": "ok"})


@dialect_route(router, "GET", "/server/info")
@moonraker_errors
def moonraker_server_info(
    request: HttpRequest, slug: str | None = None
) -> HttpResponse:
    """The connection test: PrusaSlicer needs `result.moonraker_version`."""
    caller_of(request)
    printer = None
    if slug and not is_farm(slug):
        printer = choose_printer(request, slug, Role.VIEWER)
    ready = printer is None or printer.state not in (
        Printer.State.OFFLINE,
        Printer.State.ERROR,
    )
    return JsonResponse(
        {
            "result": {
                "klippy_connected": True,
                "klippy_state": "ready" if ready else "error",
                "components": ["file_manager", "job_queue", "octoprint_compat"],
                "failed_components": [],
                "registered_directories": ["gcodes"],
                "warnings": [],
                "websocket_count": 0,
                "moonraker_version": MOONRAKER_VERSION,
                "api_version": [1, 5, 0],
                "api_version_string": "1.5.0",
            }
        }
    )


@dialect_route(router, "POST", "/server/files/upload")
@moonraker_errors
def moonraker_upload(request: HttpRequest, slug: str | None = None) -> HttpResponse:
    """Multipart `file`, `root`, `path`, `print`, `checksum` (SHA-256; 422 on mismatch).

    On `/p/farm/` the file goes to the farm queue (requirements as form fields or
    query parameters): `print_queued` is true."""
    # Who may upload here, before the body is read.
    farm = is_farm(slug)
    if farm:
        farm_caller(request, Role.OPERATOR)
    else:
        printer = choose_printer(request, slug, Role.OPERATOR)
    root = request.POST.get("root", "gcodes") or "gcodes"
    if root != "gcodes":
        raise HttpError(400, f"root {root!r} is not supported; use gcodes")
    if farm:
        return _farm_upload(request)
    to_print = truthy(request.POST.get("print"))
    checksum = request.POST.get("checksum", "").strip()
    busy = (
        running_job(printer.pk) is not None
        or printer.state != Printer.State.IDLE
        or Job.objects.filter(printer=printer, state=Job.State.QUEUED).exists()
    )
    job = upload_from_form(request, printer, queue=to_print, sha256=checksum)
    name = stored_name(job)
    response = JsonResponse(
        {
            "item": {
                "path": name,
                "root": "gcodes",
                "modified": job.created_at.timestamp(),
                "size": job.size_bytes,
                "permissions": "rw",
            },
            "print_started": to_print and not busy,
            "print_queued": to_print and busy,
            "action": "create_file",
        },
        status=201,
    )
    prefix = f"/p/{slug}" if slug else ""
    response["Location"] = request.build_absolute_uri(
        f"{prefix}/server/files/gcodes/{name}"
    )
    return response


def _farm_upload(request: HttpRequest) -> HttpResponse:
    upload = request.FILES.get("file")
    if upload is None:
        raise HttpError(400, "no file part: send the G-code as multipart field 'file'")
    checksum = request.POST.get("checksum", "")
    farm_job = store_farm_request(request, upload, sha256=checksum)
    response = JsonResponse(
        {
            "item": {
                "path": farm_job.name,
                "root": "gcodes",
                "modified": farm_job.created_at.timestamp(),
                "size": farm_job.size_bytes,
                "permissions": "r",
            },
            "print_started": False,
            "print_queued": True,
            "action": "create_file",
        },
        status=201,
    )
    response["Location"] = request.build_absolute_uri(f"/printer/farm/{farm_job.pk}")
    return response


@dialect_route(router, "GET", "/server/files/metadata")
@moonraker_errors
def moonraker_metadata(
    request: HttpRequest, filename: str = "", slug: str | None = None
) -> HttpResponse:
    """The file's analysis in Moonraker's metadata shape (Mainsail, Fluidd, apps)."""
    printer = choose_printer(request, slug, Role.VIEWER)
    job = find_job(printer, filename)
    if job is None or not job.file:
        raise HttpError(404, f"Metadata not available for <{filename}>")
    data = job.analysis_dict() or {}
    result: dict[str, Any] = {
        "filename": stored_name(job),
        "size": job.size_bytes,
        "modified": job.created_at.timestamp(),
        "uuid": job.sha256[:32],
    }
    if data.get("state") == "done":
        result.update(
            {
                "slicer": data.get("slicer") or "Unknown",
                "slicer_version": data.get("slicer_version") or "",
                "estimated_time": data.get("estimated_seconds"),
                "filament_total": data.get("filament_total"),
                "filament_weight_total": data.get("filament_weight_g"),
                "filament_type": data.get("material") or None,
                "layer_height": data.get("layer_height"),
                "first_layer_height": data.get("first_layer_height"),
                "object_height": data.get("object_height"),
                "layer_count": data.get("layers"),
                "nozzle_diameter": data.get("nozzle_diameter"),
                "thumbnails": [
                    {
                        "width": picture["width"],
                        "height": picture["height"],
                        "size": picture["size"],
                        "relative_path": f".thumbs/{job.pk}/{picture['name']}",
                    }
                    for picture in data.get("thumbnails", [])
                ],
            }
        )
    return JsonResponse({"result": result})


@dialect_route(router, "GET", "/server/files/gcodes/.thumbs/{job_id}/{name}")
@moonraker_errors
def moonraker_thumbnail(
    request: HttpRequest, job_id: int, name: str, slug: str | None = None
) -> HttpResponse:
    """A thumbnail by the `relative_path` the metadata gave (under `gcodes/`)."""
    printer = choose_printer(request, slug, Role.VIEWER)
    job = Job.objects.filter(printer=printer, pk=job_id).first()
    if job is None:
        raise HttpError(404, f"no job {job_id} on printer {printer.slug!r}")
    return serve_thumbnail(request, job, name)


@dialect_route(router, "POST", "/printer/print/start")
@moonraker_errors
def moonraker_print_start(
    request: HttpRequest, filename: str = "", slug: str | None = None
) -> HttpResponse:
    """Queue the stored file *filename* (it starts when the printer is ready)."""
    printer = choose_printer(request, slug, Role.OPERATOR)
    if not filename:
        raise HttpError(400, "give the file to print as ?filename=")
    job = find_job(printer, filename)
    if job is None:
        raise HttpError(404, f"no file {filename!r} on printer {printer.slug!r}")
    print_job(caller_of(request), job)
    return _ok()


def _job_action(request: HttpRequest, slug: str | None, action: str) -> HttpResponse:
    printer = choose_printer(request, slug, Role.OPERATOR)
    running = running_job(printer.pk)
    needs = {"pause": Job.State.PRINTING, "resume": Job.State.PAUSED}
    if running is None or (action in needs and running.state != needs[action]):
        state = running.state if running else "no job"
        raise HttpError(409, f"cannot {action}: printer {printer.slug!r} has {state}")
    run_action(
        caller_of(request),
        printer,
        action,
        audit_as=f"job.{action}",
        detail=running.name,
    )
    return _ok()


@dialect_route(router, "POST", "/printer/print/pause")
@moonraker_errors
def moonraker_print_pause(
    request: HttpRequest, slug: str | None = None
) -> HttpResponse:
    return _job_action(request, slug, "pause")


@dialect_route(router, "POST", "/printer/print/resume")
@moonraker_errors
def moonraker_print_resume(
    request: HttpRequest, slug: str | None = None
) -> HttpResponse:
    return _job_action(request, slug, "resume")


@dialect_route(router, "POST", "/printer/print/cancel")
@moonraker_errors
def moonraker_print_cancel(
    request: HttpRequest, slug: str | None = None
) -> HttpResponse:
    return _job_action(request, slug, "abort")


@dialect_route(router, "POST", "/printer/emergency_stop")
@moonraker_errors
def moonraker_emergency_stop(
    request: HttpRequest, slug: str | None = None
) -> HttpResponse:
    printer = choose_printer(request, slug, Role.OPERATOR)
    run_action(caller_of(request), printer, "emergency_stop", detail="Moonraker")
    return _ok()
