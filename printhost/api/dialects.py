"""What the slicer dialects (OctoPrint, Moonraker) share: routes, printer choice, uploads.

Their URLs carry no printer, so each path is also published under `/p/<slug>/` (a
slicer's host field `http://server/p/<slug>` then names the printer). Without a slug,
a key bound to a printer names it, else the user's default printer.
"""

from __future__ import annotations

import inspect
from typing import TYPE_CHECKING, Any

from ninja.errors import HttpError

from jobs.models import FINISHED_STATES, Job
from jobs.services import enqueue_upload, queue_job, reprint
from printers.models import Printer
from printhost.access import Forbidden
from printhost.api.common import caller_of, json_body  # noqa: F401 (re-exported)
from printhost.audit import record
from printhost.models import Role

if TYPE_CHECKING:
    from collections.abc import Callable

    from django.core.files.uploadedfile import UploadedFile
    from django.http import HttpRequest
    from ninja import Router

    from printhost.access import Caller

#: The farm pseudo-printer (`printhost.api.farm.FARM_SLUG`): uploads only.
FARM_SLUG = "farm"
#: The prefix that names a printer in front of any dialect path.
PRINTER_PREFIX = "/p/{slug}"

CHOOSE_PRINTER_HELP = (
    "no printer chosen: bind the API key to a printer, add /p/<slug>/ to the "
    "server address in the slicer, or set a default printer for your user"
)


def dialect_route(
    router: Router, method: str, path: str, **options: Any
) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Register *view* at *path* and at `/p/{slug}` + *path*.

    The view takes `slug: str | None = None`; ninja wants a path parameter without a
    default and no stray query parameter, so each route gets a thin wrapper whose
    signature says exactly that.
    """

    def register(view: Callable[..., Any]) -> Callable[..., Any]:
        name = view.__name__
        signature = inspect.signature(view, eval_str=True)
        params = [p for p in signature.parameters.values() if p.name != "slug"]

        def plain(request: HttpRequest, *args: Any, **kwargs: Any) -> Any:
            return view(request, *args, slug=None, **kwargs)

        def on_printer(request: HttpRequest, *args: Any, **kwargs: Any) -> Any:
            return view(request, *args, **kwargs)

        slug = inspect.Parameter(
            "slug", inspect.Parameter.POSITIONAL_OR_KEYWORD, annotation=str
        )
        plain.__signature__ = signature.replace(parameters=params)  # type: ignore[attr-defined]
        on_printer.__signature__ = signature.replace(  # type: ignore[attr-defined]
            parameters=[params[0], slug, *params[1:]]
        )
        for wrapper in (plain, on_printer):
            wrapper.__name__ = wrapper.__qualname__ = name
            wrapper.__doc__ = view.__doc__
            wrapper.__module__ = view.__module__
        router.add_api_operation(path, [method], plain, operation_id=name, **options)
        router.add_api_operation(
            PRINTER_PREFIX + path,
            [method],
            on_printer,
            operation_id=f"{name}_on_printer",
            **options,
        )
        return view

    return register


def choose_printer(request: HttpRequest, slug: str | None, role: int) -> Printer:
    """The printer a dialect request is about, if the caller holds *role* on it.

    Order: a key bound to a printer, the slug in `/p/<slug>/`, the user's default
    printer (or their only one). A bound key used with another slug is refused (403).
    """
    caller = caller_of(request)
    if slug == FARM_SLUG:
        raise HttpError(
            404,
            "/p/farm/ is the farm queue, not a printer: it takes uploads only "
            "(see /printer/farm for the queue)",
        )
    if slug:
        printer = Printer.objects.filter(slug=slug).first()
        if printer is None:
            raise HttpError(404, f"Unknown printer {slug!r}")
    else:
        printer = caller.default_printer(role) or caller.default_printer(Role.VIEWER)
        if printer is None:
            if not Printer.objects.exists():
                raise HttpError(409, "no printer is set up yet: add one first")
            if not caller.printers(Role.VIEWER) and caller.bound_printer_id is None:
                raise Forbidden("you hold no role on any printer")
            raise HttpError(409, CHOOSE_PRINTER_HELP)
    caller.require(printer, role)
    return printer


def truthy(value: object) -> bool:
    """OctoPrint and Moonraker send booleans as form strings ("true", "1")."""
    if isinstance(value, bool):
        return value
    return str(value or "").strip().lower() in {"true", "1", "yes", "on"}


def upload_from_form(
    request: HttpRequest,
    printer: Printer,
    *,
    queue: bool,
    sha256: str = "",
    action: str = "job.upload",
) -> Job:
    """Store the multipart `file` part as a job (queued when *queue*), audited."""
    upload: UploadedFile | None = request.FILES.get("file")
    if upload is None:
        raise HttpError(400, "no file part: send the G-code as multipart field 'file'")
    caller = caller_of(request)
    name = upload.name or "upload.gcode"
    job = enqueue_upload(
        printer,
        upload,
        name=name,
        origin=caller.origin,
        user=caller.user if caller.authenticated else None,
        queue=queue,
        sha256=sha256,
    )
    detail = f"{job.name} ({job.size_bytes} bytes){' queued' if queue else ''}"
    record(caller, action, printer=printer, job=job, detail=detail)
    return job


def stored_name(job: Job) -> str:
    """The name a dialect shows for a job's file (unique in the printer's storage)."""
    return job.file.rsplit("/", 1)[-1]


def find_job(printer: Printer, name: str) -> Job | None:
    """The newest job whose stored file (or, failing that, display name) is *name*."""
    name = name.strip("/").rsplit("/", 1)[-1]
    if not name:
        return None
    jobs = Job.objects.filter(printer=printer).order_by("-created_at", "-id")
    return (
        jobs.filter(file__endswith=f"/{name}").first() or jobs.filter(name=name).first()
    )


def print_job(caller: Caller, job: Job) -> Job:
    """Queue *job* for printing: a stored one joins the queue, a finished one is
    printed again; a queued or running one is left alone (asking twice is harmless).
    """
    if job.state == Job.State.STORED:
        queue_job(job)
        job.refresh_from_db()
    elif job.state in FINISHED_STATES:
        job = reprint(
            job,
            origin=caller.origin,
            user=caller.user if caller.authenticated else None,
        )
    else:
        return job
    record(caller, "job.queue", printer=job.printer, job=job, detail=job.name)
    return job


def waits_for_bed(printer: Printer) -> bool:
    """A queued job will not start by itself: the bed must be confirmed clear first."""
    return printer.state == Printer.State.WAITSTART


def elapsed_seconds(job: Job) -> int | None:
    """Whole seconds since the job started (OctoPrint's `printTime`)."""
    elapsed = job.elapsed_seconds()
    return None if elapsed is None else int(elapsed)
