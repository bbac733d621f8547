"""Resume a stopped print from a line or a layer: choose, preview the preamble, start.

    GET  /printer/resume/<slug>?id=<job>      where it can start: the last acked
                                              line, the layers (Z, time), plans
    POST /printer/resume/<slug>               id, and line or layer (neither: the
                                              line after the last acked one):
                                              a plan, made by a Celery task
    GET  /printer/resume/<slug>?plan=<plan>   the plan: pending, then ready with
                                              its preamble and machine state
    POST /printer/resume/<slug>/start         plan: queue the resumed run first

Nothing reaches the printer before `start`: the preamble is shown first. Refusals
(a job still printing, no analysis, a line beyond the file, a plan not ready) are
4xx with the reason, and change nothing.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from django.http import HttpRequest, HttpResponse  # noqa: TC002 (ninja reads view hints)
from ninja import Router
from ninja.errors import HttpError

from jobs.analysing import analysis_of
from jobs.models import Job, ResumePlan
from jobs.resume.planning import ResumeRefused, request_plan, start_plan
from printhost import audit
from printhost.api.common import (
    caller_of,
    envelope,
    job_of,
    json_body,
    parse_int,
    printer_for,
    request_params,
)
from printhost.models import Role

if TYPE_CHECKING:
    from printers.models import Printer

router = Router(tags=["printer (resume)"])


def _params(request: HttpRequest) -> dict[str, str]:
    params = request_params(request)
    if (request.content_type or "") == "application/json":
        params.update({k: str(v) for k, v in json_body(request).items()})
    return params


def _plan(printer: Printer, params: dict[str, str]) -> ResumePlan:
    plan_id = parse_int(params.get("plan"), "plan", default=-1, minimum=1)
    if plan_id < 0:
        raise HttpError(400, "plan is required")
    plan = ResumePlan.objects.filter(pk=plan_id, job__printer=printer).first()
    if plan is None:
        raise HttpError(404, f"no resume plan {plan_id} on printer {printer.slug!r}")
    return plan


def options_of(job: Job) -> dict[str, Any]:
    """Where *job* can resume: the default line and the layers to choose from."""
    analysed = analysis_of(job)
    layers = analysed.layers if analysed is not None else []
    plans = ResumePlan.objects.filter(job=job).order_by("-pk")[:10]
    return {
        "job": job.pk,
        "state": job.state,
        "lines": job.line_count,
        "last_line": job.lines_acked,
        "layers": [
            {"index": i, "z": layer.z, "line": layer.line, "time": round(layer.time, 1)}
            for i, layer in enumerate(layers)
        ],
        "plans": [plan.as_dict() for plan in plans],
    }


@router.get("/printer/resume/{slug}", summary="Resume: options or a plan")
def resume_info(request: HttpRequest, slug: str) -> HttpResponse:
    """`id=<job>`: where the job can resume; `plan=<id>`: a plan and its preamble."""
    printer = printer_for(request, slug, Role.VIEWER)
    params = request_params(request)
    if params.get("plan"):
        return envelope(_plan(printer, params).as_dict())
    return envelope(options_of(job_of(printer, params)))


def _optional(params: dict[str, str], name: str) -> int | None:
    if params.get(name, "") == "":
        return None
    return parse_int(params[name], name, default=0)


@router.post("/printer/resume/{slug}", summary="Resume: make a plan")
def resume_plan(request: HttpRequest, slug: str) -> HttpResponse:
    """Plan a resume of job `id` at `line` (a command index, 0-based) or `layer`
    (0-based), by default after the last acknowledged line. The plan is pending
    until a Celery worker has read the file; GET it with `plan=<id>`."""
    printer = printer_for(request, slug, Role.OPERATOR)
    caller = caller_of(request)
    params = _params(request)
    job = job_of(printer, params)
    try:
        plan = request_plan(
            job,
            line=_optional(params, "line"),
            layer=_optional(params, "layer"),
            user=caller.user if caller.authenticated else None,
            origin=caller.origin,
        )
    except ResumeRefused as error:
        raise HttpError(error.status, str(error)) from None
    audit.record(caller, "job.resume_plan", printer=printer, job=job)
    return envelope(plan.as_dict())


@router.post("/printer/resume/{slug}/start", summary="Resume: start a plan")
def resume_start(request: HttpRequest, slug: str) -> HttpResponse:
    """Queue the resumed run of a ready plan ahead of the printer's queue."""
    printer = printer_for(request, slug, Role.OPERATOR)
    caller = caller_of(request)
    plan = _plan(printer, _params(request))
    try:
        resumed = start_plan(
            plan,
            user=caller.user if caller.authenticated else None,
            origin=caller.origin,
        )
    except ResumeRefused as error:
        raise HttpError(error.status, str(error)) from None
    audit.record(caller, "job.resume", printer=printer, job=resumed)
    return envelope(resumed.as_dict())
