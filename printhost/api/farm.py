"""The farm's API: its queue, a farm job's changes, and what each printer has loaded.

- `GET /printer/farm`: the queue (waiting jobs in order, each with its
  requirements, why it waits and the printer it would go to now; then the latest
  given and cancelled ones, with where they went), the printers grouped by worker
  host and by material, and each host's heartbeat.
- `GET|PATCH /printer/farm/{id}`: one farm job; change its `priority`,
  `deadline` or requirements while it waits (409 once a printer has it).
- `POST /printer/farm/{id}/cancel`: take a waiting job out of the queue.
- `POST /printer/loaded/{slug}`: what the printer has loaded (`material`,
  `colour`, `nozzle`), stamped with who set it and when.

Uploads reach the farm through the usual upload paths with `farm` as the printer:
`/printer/job/farm?a=upload`, `/p/farm/api/files/local`,
`/p/farm/server/files/upload` (`store_farm_request`). Requirements come as form
fields or query parameters.

Who may: the farm may give a job to any printer, so queuing, changing and
cancelling farm jobs needs the operator role on every printer (a role with no
printer), and seeing the farm the viewer role on every printer; a key bound to
one printer is refused (403). Setting what a printer has loaded needs the
operator role on that printer.
"""

from __future__ import annotations

from difflib import get_close_matches
from typing import TYPE_CHECKING, Any

from django.core.exceptions import ValidationError as ModelValidationError
from django.http import HttpRequest, JsonResponse  # noqa: TC002 (ninja reads hints)
from django.utils import timezone
from ninja import Router
from ninja.errors import HttpError

from jobs.farm.matching import (
    facts_of,
    farm_printers,
    plan,
    printer_rows,
    waiting_jobs,
)
from jobs.farm.models import FarmJob
from jobs.farm.requirements import BadRequirement, parse_nozzle, parse_requirements
from jobs.farm.storing import (
    NotWaiting,
    cancel,
    change,
    parse_deadline,
    parse_priority,
    store_farm_upload,
)
from printers.hosts import WorkerHost
from printers.models import Printer
from printhost.api.common import caller_of, envelope, json_body, printer_for
from printhost.audit import record
from printhost.models import Role

if TYPE_CHECKING:
    from collections.abc import Iterable

    from django.core.files.uploadedfile import UploadedFile

    from jobs.farm.requirements import PrinterFacts
    from printhost.access import Caller

router = Router(tags=["Farm"])

#: The pseudo-printer's slug in upload URLs (reserved: no printer may take it).
FARM_SLUG = "farm"
#: Given or cancelled farm jobs listed after the waiting ones.
RECENT_SHOWN = 30
#: Requirement and ordering fields an upload may carry (form fields or query).
UPLOAD_FIELDS = (
    "material", "colour", "color", "nozzle", "nozzle_diameter", "profile", "tags",
    "priority", "deadline",
)  # fmt: skip


#: Fields of the slicers' dialects that read like a requirement's name, but are not.
NOT_MISSPELT = frozenset({"file"})


def is_farm(slug: str | None) -> bool:
    """The URL names the farm rather than one printer."""
    return slug == FARM_SLUG


def farm_caller(request: HttpRequest, role: int) -> Caller:
    """The caller, if they may act on the farm at *role* (401 / 403 otherwise)."""
    caller = caller_of(request)
    caller.require_farm(role)
    return caller


def upload_values(request: HttpRequest) -> dict[str, Any]:
    """Requirement fields of an upload: query parameters, then form fields; `tags`
    may repeat. BadRequirement for a field that looks like a misspelt one
    (`materal`, `Material`, `tag`): the job would wait for any printer instead."""
    values: dict[str, Any] = {}
    for source in (request.GET, request.POST if request.method == "POST" else {}):
        for name in source:
            if name in UPLOAD_FIELDS:
                items = source.getlist(name)  # type: ignore[union-attr]
                values[name] = items if name == "tags" else items[-1]
            elif name not in NOT_MISSPELT and (
                near := get_close_matches(name.lower(), UPLOAD_FIELDS, 1, 0.7)
            ):
                raise BadRequirement(
                    f"unknown field {name[:40]!r}: did you mean {near[0]!r}? (a farm "
                    f"upload takes {', '.join(UPLOAD_FIELDS)})"
                )
    return values


def store_farm_request(
    request: HttpRequest, file: UploadedFile, *, name: str = "", sha256: str = ""
) -> FarmJob:
    """Queue an upload for the farm with the request's requirements, audited.

    Bad requirements are refused (400) before the file is stored; a given *sha256*
    must be the file's (ChecksumMismatch: nothing stored, nothing audited).
    """
    caller = farm_caller(request, Role.OPERATOR)
    try:
        values = upload_values(request)
        requirements = parse_requirements(values)
        priority = parse_priority(values.get("priority"))
        deadline = parse_deadline(values.get("deadline"))
    except BadRequirement as error:
        raise HttpError(400, str(error)) from None
    farm_job = store_farm_upload(
        file,
        name=name or file.name or "upload.gcode",
        requirements=requirements,
        priority=priority,
        deadline=deadline,
        origin=caller.origin,
        user=caller.user if caller.authenticated else None,
        sha256=sha256,
    )
    record(
        caller,
        "farm.upload",
        detail=f"farm job {farm_job.pk}: {farm_job.name} ({farm_job.size_bytes} "
        f"bytes) for {requirements.describe()}",
    )
    return farm_job


# -- the queue -------------------------------------------------------------------------


def queue_entries(printers: list[PrinterFacts] | None = None) -> list[dict[str, Any]]:
    """Waiting jobs in queue order with their "would go to" among the farm's
    *printers* (read here unless given), then the latest others."""
    waiting = waiting_jobs()
    entries = [
        farm_job.as_dict(
            would_go_to=decision.printer.slug if decision.printer else None
        )
        for farm_job, decision in plan(
            waiting, farm_printers() if printers is None else printers
        )
    ]
    recent = (
        FarmJob.objects.exclude(state=FarmJob.State.WAITING)
        .select_related("analysis", "printer", "job")
        .defer("analysis__result")
        .order_by("-id")[:RECENT_SHOWN]
    )
    return entries + [farm_job.as_dict() for farm_job in recent]


def printer_entries(rows: Iterable[Printer]) -> list[dict[str, Any]]:
    """Every printer of *rows* (`printer_rows()`) with what the farm reads of it
    (farm or not)."""
    out = []
    for printer in rows:
        facts = facts_of(printer, has_work=printer.has_work)
        out.append(
            {
                "slug": printer.slug,
                "name": printer.name,
                "host": facts.extra["host"],
                "state": printer.state,
                "state_label": Printer.State(printer.state).label
                if printer.state in Printer.State.values
                else printer.state,
                "farm": printer.farm and printer.enabled and not printer.is_grbl,
                "free": not facts.extra["busy"],
                "busy": facts.extra["busy"],
                **loaded_of(printer),
                "profile": printer.profile,
                "tags": list(printer.tags or ()),
                "build_volume": printer.build_volume or None,
            }
        )
    return out


def loaded_of(printer: Printer) -> dict[str, Any]:
    """What the printer has loaded, and who said so when."""
    return {
        "material": printer.material,
        "colour": printer.colour,
        "nozzle_diameter": printer.nozzle_diameter,
        "loaded_by": printer.loaded_by,
        "loaded_at": printer.loaded_at.isoformat() if printer.loaded_at else None,
    }


def overview() -> dict[str, Any]:
    """The whole farm view: queue, printers, hosts (four queries however many
    printers and jobs: the printers are read once for the queue and the list)."""
    rows = list(printer_rows())
    return {
        "jobs": queue_entries(farm_printers(rows)),
        "printers": printer_entries(rows),
        "hosts": [host.as_dict() for host in WorkerHost.objects.all()],
    }


@router.get("/printer/farm", summary="The farm queue, its printers and hosts")
def farm_list(request: HttpRequest) -> JsonResponse:
    """Waiting jobs in queue order (requirements, `reason`, `would_go_to`), then the
    latest given or cancelled ones (`printer`, `job`); the printers (host, state,
    what is loaded, `free` or why `busy`); the worker hosts' heartbeats."""
    farm_caller(request, Role.VIEWER)
    return envelope(overview())


def _farm_job(farm_id: int) -> FarmJob:
    farm_job = (
        FarmJob.objects.select_related("analysis", "printer", "job")
        .defer("analysis__result")
        .filter(pk=farm_id)
        .first()
    )
    if farm_job is None:
        raise HttpError(404, f"no farm job {farm_id}")
    return farm_job


@router.get("/printer/farm/{farm_id}", summary="One farm job")
def farm_job_detail(request: HttpRequest, farm_id: int) -> JsonResponse:
    farm_caller(request, Role.VIEWER)
    return envelope(_farm_job(farm_id).as_dict())


@router.patch("/printer/farm/{farm_id}", summary="Change a waiting farm job")
def farm_job_change(request: HttpRequest, farm_id: int) -> JsonResponse:
    """JSON: `priority` (-1000..1000), `deadline` (ISO 8601 or null), `material`,
    `colour`, `nozzle`, `profile`, `tags` ("" or null clears one). 400 for a bad
    value (nothing changes), 409 once a printer has the job."""
    caller = farm_caller(request, Role.OPERATOR)
    farm_job = _farm_job(farm_id)
    changes = json_body(request)
    try:
        farm_job = change(farm_job, changes)
    except BadRequirement as error:
        raise HttpError(400, str(error)) from None
    except NotWaiting as error:
        raise HttpError(409, str(error)) from None
    record(caller, "farm.change", detail=f"farm job {farm_id}: {changes}")
    return envelope(_farm_job(farm_id).as_dict())


@router.post("/printer/farm/{farm_id}/cancel", summary="Cancel a waiting farm job")
def farm_job_cancel(request: HttpRequest, farm_id: int) -> JsonResponse:
    """409 once a printer has the job: act on the printer's job instead."""
    caller = farm_caller(request, Role.OPERATOR)
    farm_job = _farm_job(farm_id)
    try:
        cancel(farm_job)
    except NotWaiting as error:
        raise HttpError(409, str(error)) from None
    record(caller, "farm.cancel", detail=f"farm job {farm_id}: {farm_job.name}")
    return envelope(_farm_job(farm_id).as_dict())


# -- what a printer has loaded ---------------------------------------------------------

LOADED_FIELDS = ("material", "colour", "color", "nozzle", "nozzle_diameter")


@router.post("/printer/loaded/{slug}", summary="Set what a printer has loaded")
def set_loaded(request: HttpRequest, slug: str) -> JsonResponse:
    """`material`, `colour`, `nozzle` (mm) as JSON or form fields; a field left out
    stays, "" (or null) clears it. Operator on the printer."""
    printer = printer_for(request, slug, Role.OPERATOR)
    caller = caller_of(request)
    if request.content_type == "application/json":
        values = json_body(request)
    else:
        values = {k: request.POST.get(k) for k in request.POST}
    unknown = sorted(set(values) - set(LOADED_FIELDS))
    if unknown:
        raise HttpError(
            400, f"not a loaded field: {', '.join(unknown)} (material, colour, nozzle)"
        )
    if not values:
        raise HttpError(400, "send material, colour or nozzle")
    fields = _loaded_fields(values)
    for name, value in fields.items():
        setattr(printer, name, value)
    try:
        printer.full_clean(
            exclude=[f.name for f in printer._meta.fields if f.name not in fields]
        )
    except ModelValidationError as error:
        text = "; ".join(f"{k}: {' '.join(v)}" for k, v in error.message_dict.items())
        raise HttpError(400, f"invalid: {text}") from None
    printer.loaded_by = (getattr(caller.user, "username", "") or caller.origin)[:100]
    printer.loaded_at = timezone.now()
    printer.save(update_fields=[*fields, "loaded_by", "loaded_at"])
    record(caller, "printer.loaded", printer=printer, detail=str(fields))
    return envelope({"slug": printer.slug, **loaded_of(printer)})


def _loaded_fields(values: dict[str, Any]) -> dict[str, Any]:
    """The printer fields *values* set, checked (400 with the reason)."""
    try:
        asked = parse_requirements(
            {k: ("" if v is None else v) for k, v in values.items()}
        )
        fields: dict[str, Any] = {}
        if "material" in values:
            fields["material"] = asked.material
        if "colour" in values or "color" in values:
            fields["colour"] = asked.colour
        if "nozzle" in values or "nozzle_diameter" in values:
            fields["nozzle_diameter"] = parse_nozzle(
                values.get("nozzle", values.get("nozzle_diameter"))
            )
    except BadRequirement as error:
        raise HttpError(400, str(error)) from None
    return fields
