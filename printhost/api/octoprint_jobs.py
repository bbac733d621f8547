"""OctoPrint's files and job endpoints: uploads, select and print, job state and control.

The slicers' upload (`POST /api/files/local`, 201 with an absolute `Location`), Cura's
follow-up select+print on that `Location`, and `/api/job` for progress and
start / cancel / restart / pause. The rest of the dialect is in `octoprint.py`.
"""

from __future__ import annotations

import shutil
from typing import TYPE_CHECKING, Any

from django.http import HttpRequest, HttpResponse, JsonResponse
from ninja import Router
from ninja.errors import HttpError

from jobs.models import Job, running_job
from jobs.services import reprint, storage_dir
from printhost.api.analysis import largest_thumbnail, serve_thumbnail
from printhost.api.common import caller_of
from printhost.api.dialects import (
    choose_printer,
    dialect_route,
    elapsed_seconds,
    find_job,
    json_body,
    print_job,
    stored_name,
    truthy,
    upload_from_form,
)
from printhost.api.farm import farm_caller, is_farm, store_farm_request
from printhost.api.octoprint import no_content, state_and_flags
from printhost.audit import record
from printhost.clients import run_action
from printhost.models import Role

if TYPE_CHECKING:
    from printers.models import Printer

router = Router(tags=["OctoPrint dialect"])


# -- files ----------------------------------------------------------------------------


def _file_info(request: HttpRequest, job: Job, prefix: str) -> dict[str, Any]:
    name = stored_name(job)
    resource = request.build_absolute_uri(f"{prefix}/api/files/local/{name}")
    return {
        "name": name,
        "display": job.name,
        "path": name,
        "type": "machinecode",
        "typePath": ["machinecode", "gcode"],
        "origin": "local",
        "size": job.size_bytes,
        "date": int(job.created_at.timestamp()),
        "hash": job.sha256,
        "refs": {"resource": resource, "download": resource},
        **_analysis_fields(job),
    }


def _analysis_fields(job: Job) -> dict[str, Any]:
    """OctoPrint's `gcodeAnalysis` and `thumbnail` (relative to the API's base, as
    the PrusaSlicer-thumbnails plugin gives it) once the file is analysed."""
    data = job.analysis_dict()
    if not data or data["state"] != "done":
        return {}
    fields: dict[str, Any] = {"gcodeAnalysis": octoprint_analysis(data)}
    picture = largest_thumbnail(job)
    if picture:
        fields["thumbnail"] = f"api/files/thumbnail/{job.pk}/{picture}"
        fields["thumbnail_src"] = "printhost"
    return fields


def octoprint_analysis(data: dict[str, Any]) -> dict[str, Any]:
    """A printhost analysis summary in OctoPrint's `gcodeAnalysis` shape."""
    filament = {}
    total = data.get("filament_total") or 0.0
    volume = data.get("filament_volume_mm3") or 0.0
    for tool, length in enumerate(data.get("filament_mm") or []):
        share = length / total if total else 0.0
        filament[f"tool{tool}"] = {
            "length": length,
            "volume": round(volume * share / 1000, 3),  # cm³
        }
    out: dict[str, Any] = {
        "estimatedPrintTime": data.get("estimated_seconds"),
        "filament": filament,
    }
    box = data.get("bbox")
    if box:
        (x0, y0, z0), (x1, y1, z1) = box
        out["dimensions"] = {
            "width": round(x1 - x0, 3), "depth": round(y1 - y0, 3),
            "height": round(z1 - z0, 3),
        }  # fmt: skip
        out["printingArea"] = {
            "minX": x0, "minY": y0, "minZ": z0, "maxX": x1, "maxY": y1, "maxZ": z1,
        }  # fmt: skip
    return out


@dialect_route(router, "GET", "/api/files")
def octoprint_files(request: HttpRequest, slug: str | None = None) -> JsonResponse:
    """Every stored file of the printer, newest first, with its analysis."""
    return _file_list(request, slug)


@dialect_route(router, "GET", "/api/files/local")
def octoprint_local_files(
    request: HttpRequest, slug: str | None = None
) -> JsonResponse:
    return _file_list(request, slug)


def _file_list(request: HttpRequest, slug: str | None) -> JsonResponse:
    printer = choose_printer(request, slug, Role.VIEWER)
    jobs = (
        Job.objects.filter(printer=printer)
        .exclude(file="")
        .select_related("printer", "analysis")
        .defer("analysis__result")
        .order_by("-created_at", "-id")
    )
    seen: set[str] = set()
    files = []
    for job in jobs[:500]:
        name = stored_name(job)
        if name not in seen:
            seen.add(name)
            files.append(_file_info(request, job, dialect_prefix(slug)))
    usage = shutil.disk_usage(storage_dir(printer))
    return JsonResponse({"files": files, "free": usage.free, "total": usage.total})


@dialect_route(router, "GET", "/api/files/thumbnail/{job_id}/{name}")
def octoprint_thumbnail(
    request: HttpRequest, job_id: int, name: str, slug: str | None = None
) -> HttpResponse:
    printer = choose_printer(request, slug, Role.VIEWER)
    job = (
        Job.objects.filter(printer=printer, pk=job_id)
        .select_related("printer", "analysis")
        .first()
    )
    if job is None:
        raise HttpError(404, f"no job {job_id} on printer {printer.slug!r}")
    return serve_thumbnail(request, job, name)


def dialect_prefix(slug: str | None) -> str:
    """What goes before `/api/...` in a resource URL: `/p/<slug>` or nothing."""
    return f"/p/{slug}" if slug else ""


def upload_answer(
    origin: str, info: dict[str, Any], *, done: bool, select: bool, to_print: bool
) -> JsonResponse:
    """OctoPrint's 201 to an upload: the file under its origin, and its Location."""
    response = JsonResponse(
        {
            "files": {origin: info},
            "done": done,
            "effectiveSelect": select,
            "effectivePrint": to_print,
        },
        status=201,
    )
    response["Location"] = info["refs"]["resource"]
    return response


@dialect_route(router, "POST", "/api/files/local")
def octoprint_upload(request: HttpRequest, slug: str | None = None) -> JsonResponse:
    """Upload (multipart `file`, `path`, `select`, `print`); print = join the queue.

    On `/p/farm/` the file goes to the farm queue (whatever `print` says: the farm
    keeps no files of its own), with requirements as form fields or query
    parameters."""
    if is_farm(slug):
        return _farm_upload(request)
    printer = choose_printer(request, slug, Role.OPERATOR)
    if "foldername" in request.POST and "file" not in request.FILES:
        raise HttpError(400, "folders are not supported; upload a file")
    to_print = truthy(request.POST.get("print"))
    select = truthy(request.POST.get("select")) or to_print
    job = upload_from_form(request, printer, queue=to_print)
    info = _file_info(request, job, dialect_prefix(slug))
    return upload_answer("local", info, done=True, select=select, to_print=to_print)


def _farm_upload(request: HttpRequest) -> JsonResponse:
    farm_caller(request, Role.OPERATOR)  # before the body is read
    upload = request.FILES.get("file")
    if upload is None:
        raise HttpError(400, "no file part: send the G-code as multipart field 'file'")
    farm_job = store_farm_request(request, upload)
    resource = request.build_absolute_uri(f"/printer/farm/{farm_job.pk}")
    info = {
        "name": farm_job.name,
        "display": farm_job.name,
        "path": farm_job.name,
        "type": "machinecode",
        "typePath": ["machinecode", "gcode"],
        "origin": "local",
        "size": farm_job.size_bytes,
        "date": int(farm_job.created_at.timestamp()),
        "hash": farm_job.sha256,
        "refs": {"resource": resource, "download": resource},
    }
    return upload_answer("local", info, done=True, select=False, to_print=True)


@dialect_route(router, "GET", "/api/files/local/{path:filename}")
def octoprint_file(
    request: HttpRequest, filename: str, slug: str | None = None
) -> JsonResponse:
    printer = choose_printer(request, slug, Role.VIEWER)
    job = find_job(printer, filename)
    if job is None:
        raise HttpError(404, f"no file {filename!r} on printer {printer.slug!r}")
    return JsonResponse(_file_info(request, job, dialect_prefix(slug)))


@dialect_route(router, "POST", "/api/files/local/{path:filename}")
def octoprint_file_command(
    request: HttpRequest, filename: str, slug: str | None = None
) -> HttpResponse:
    """`{"command": "select", "print": true}`: queue the file (a queued one stays)."""
    printer = choose_printer(request, slug, Role.OPERATOR)
    body = json_body(request)
    command = body.get("command")
    if command != "select":
        raise HttpError(400, f"unknown command {command!r}; use select")
    job = find_job(printer, filename)
    if job is None:
        raise HttpError(404, f"no file {filename!r} on printer {printer.slug!r}")
    if truthy(body.get("print")):
        print_job(caller_of(request), job)
    return no_content()


# -- job ------------------------------------------------------------------------------


def _current_job(printer: Printer) -> Job | None:
    """The running job, else the next queued one, else the newest stored or done."""
    jobs = Job.objects.filter(printer=printer)
    return (
        running_job(printer.pk)
        or jobs.filter(state=Job.State.QUEUED).order_by("position", "id").first()
        or jobs.order_by("-created_at", "-id").first()
    )


@dialect_route(router, "GET", "/api/job")
def octoprint_job(request: HttpRequest, slug: str | None = None) -> JsonResponse:
    printer = choose_printer(request, slug, Role.VIEWER)
    job = _current_job(printer)
    file: dict[str, Any] = {"name": None, "path": None, "origin": None, "size": None}
    completion = print_time = time_left = origin = estimated = filament = None
    if job is not None:
        file = {
            "name": job.name,
            "path": stored_name(job),
            "display": job.name,
            "origin": "local",
            "size": job.size_bytes,
            "date": int(job.created_at.timestamp()),
        }
        if job.state != Job.State.STORED:
            completion = round(job.progress * 100, 2)
        print_time = elapsed_seconds(job)
        timing = job.timing()
        if timing["eta"] is not None:
            time_left, origin = int(timing["eta"]), timing["eta_origin"]
        data = job.analysis_dict()
        if data and data["state"] == "done":
            found = octoprint_analysis(data)
            estimated, filament = found["estimatedPrintTime"], found["filament"]
            if timing["time_progress"] is not None:
                completion = timing["time_progress"]
    state = state_and_flags(printer)["text"]
    return JsonResponse(
        {
            "job": {
                "file": file,
                "estimatedPrintTime": estimated,
                "lastPrintTime": None,
                "filament": filament,
                "user": None,
            },
            "progress": {
                "completion": completion,
                "filepos": job.bytes_acked if job else None,
                "printTime": print_time,
                "printTimeLeft": time_left,
                "printTimeLeftOrigin": origin,
            },
            "state": state,
        }
    )


@dialect_route(router, "POST", "/api/job")
def octoprint_job_command(
    request: HttpRequest, slug: str | None = None
) -> HttpResponse:
    """start / cancel / restart / pause (action pause, resume, toggle): 204 or 409."""
    printer = choose_printer(request, slug, Role.OPERATOR)
    body = json_body(request)
    command = body.get("command")
    caller = caller_of(request)
    running = running_job(printer.pk)
    if command == "start":
        if running is not None:
            raise HttpError(409, f"{running.name} is already printing")
        stored = (
            Job.objects.filter(printer=printer, state=Job.State.STORED)
            .order_by("-created_at", "-id")
            .first()
        )
        if stored is not None:
            print_job(caller, stored)
        elif not Job.objects.filter(printer=printer, state=Job.State.QUEUED).exists():
            raise HttpError(409, "no file is selected: upload one first")
        return no_content()
    if command == "cancel":
        if running is None:
            raise HttpError(409, "no job is printing")
        run_action(caller, printer, "abort", audit_as="job.abort", detail=running.name)
        return no_content()
    if command == "restart":
        if running is None or running.state != Job.State.PAUSED:
            raise HttpError(409, "only a paused job can be restarted")
        run_action(caller, printer, "abort", audit_as="job.abort", detail="restart")
        again = reprint(running, origin=caller.origin, user=caller.user)
        record(caller, "job.queue", printer=printer, job=again, detail=again.name)
        return no_content()
    if command == "pause":
        if running is None:
            raise HttpError(409, "no job is printing")
        action = str(body.get("action", "toggle"))
        if action == "toggle":
            action = "resume" if running.state == Job.State.PAUSED else "pause"
        if action not in ("pause", "resume"):
            raise HttpError(
                400, f"unknown action {action!r}; use pause, resume, toggle"
            )
        if (action == "pause") != (running.state == Job.State.PRINTING):
            raise HttpError(409, f"{running.name} is {running.state}; cannot {action}")
        run_action(
            caller, printer, action, audit_as=f"job.{action}", detail=running.name
        )
        return no_content()
    raise HttpError(
        400, f"unknown command {command!r}; use start, cancel, restart or pause"
    )
