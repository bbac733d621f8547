"""The browser pages: dashboard, printer, job, account.

Views are thin: they check the role, read what the page shows first and render it,
so a page is useful before its script runs. Every change a page makes goes through
the JSON API with `fetch` (the same code path slicers and hosts use), never here.
"""

from __future__ import annotations

from datetime import datetime
from typing import TYPE_CHECKING, Any

from django.contrib.auth.decorators import login_required
from django.db.models import Max
from django.shortcuts import get_object_or_404, render

from jobs.listing import printer_jobs
from jobs.models import Job
from printers.models import Printer, ResponseLine
from printhost.access import Caller
from printhost.api.shapes import printer_state
from printhost.models import ApiKey, Role

if TYPE_CHECKING:
    from django.http import HttpRequest, HttpResponse

#: Response lines rendered with the printer page; the websocket sends the rest.
TERMINAL_LINES = 200
#: Finished jobs listed in a printer's queue panel (newest first after the queue);
#: printer.js asks the job list for as many (`data-finished`) when it reloads it.
PANEL_FINISHED = 20


def clock(seconds: float | None) -> str:
    """Seconds as `m:ss` or `h:mm:ss`; a dash when unknown."""
    if seconds is None:
        return "—"
    total = max(0, int(seconds))
    hours, rest = divmod(total, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


def temps_text(temperatures: dict[str, Any] | None) -> str:
    """`T0 205/210 °C · B 60/60 °C`: current/target of each heater."""
    parts = []
    for name, reading in (temperatures or {}).items():
        if not isinstance(reading, dict):
            continue
        current = reading.get("current")
        target = reading.get("target")
        now = "—" if current is None else f"{current:.0f}"
        goal = "—" if target is None else f"{target:.0f}"
        parts.append(f"{name} {now}/{goal} °C")
    return " · ".join(parts) or "—"


def state_label(state: str) -> str:
    """The words a person reads for a printer state."""
    try:
        return Printer.State(state).label
    except ValueError:
        return state


def caller_of_page(request: HttpRequest) -> Caller:
    """The logged-in browser user as an API caller (no key: the session)."""
    return Caller(
        client="http", user=request.user, address=request.META.get("REMOTE_ADDR", "")
    )


def forbidden(request: HttpRequest, message: str) -> HttpResponse:
    """The styled 403 page."""
    return render(request, "403.html", {"message": message}, status=403)


def pick_thumbnail(job: dict[str, Any] | None, smallest: int) -> str:
    """The address of the smallest thumbnail at least *smallest* px wide (else the
    largest), or ""; the same choice as `pickThumbnail` in api.js."""
    pictures = ((job or {}).get("analysis") or {}).get("thumbnails") or []
    if not pictures:
        return ""
    wide = [p for p in pictures if p["width"] >= smallest]
    chosen = min(wide, key=lambda p: p["width"]) if wide else pictures[0]
    return chosen["url"]


def metres(millimetres: float | None) -> str:
    return "—" if millimetres is None else f"{millimetres / 1000:.2f} m"


def job_view(job: dict[str, Any] | None) -> dict[str, Any]:
    """A job's progress as the pages show it first (api.js `showJob` keeps it live)."""
    if not job:
        return {"percent": 0, "elapsed": clock(None), "remaining": clock(None),
                "ends": "—", "layer": "—", "filament": "—", "thumbnail": ""}  # fmt: skip
    ends = job.get("ends_at")
    layer = job.get("layer")
    return {
        "percent": job["time_progress"]
        if job.get("time_progress") is not None
        else job["progress"],
        "elapsed": clock(job["elapsed"]),
        "remaining": clock(job["eta"]),
        "ends": datetime.fromisoformat(ends).astimezone().strftime("%H:%M")
        if ends
        else "—",
        "layer": f"{layer} / {job['layers']}" if layer else "—",
        "filament": metres(job.get("filament_used")),
        "thumbnail": pick_thumbnail(job, 96),
    }


def analysis_figures(analysis: dict[str, Any]) -> dict[str, str]:
    """The job page's analysis panel, in words."""
    box = analysis.get("bbox")
    size = "—"
    if box:
        (x0, y0, z0), (x1, y1, z1) = box
        size = f"{x1 - x0:.1f} \u00d7 {y1 - y0:.1f} \u00d7 {z1 - z0:.1f} mm"
    weight = analysis.get("filament_weight_g")
    filament = metres(analysis.get("filament_total"))
    if weight:
        filament += f", {weight:.1f} g"
    slicer_time = analysis.get("slicer_estimated_seconds")
    return {
        "time": clock(analysis.get("estimated_seconds")),
        "heating": clock(analysis.get("heating_seconds")),
        "slicer_time": clock(slicer_time) if slicer_time else "",
        "filament": filament,
        "size": size,
    }


def card(printer: Printer, caller: Caller) -> dict[str, Any]:
    """What a printer card or the printer page shows first."""
    state = printer_state(printer)
    job = state["job"]
    return {
        "printer": printer,
        "state": state,
        "state_label": state_label(printer.state),
        "job": job,
        "view": job_view(job),
        "temps": temps_text(printer.temperatures),
        "operator": caller.can(printer, Role.OPERATOR),
        "admin": caller.can(printer, Role.ADMIN),
    }


@login_required
def dashboard(request: HttpRequest) -> HttpResponse:
    """Every printer the user may view, as a card."""
    caller = caller_of_page(request)
    printers = caller.printers(Role.VIEWER)
    cards = [card(p, caller) for p in printers]
    return render(
        request, "dashboard.html", {"cards": cards, "hosts": hosts_of(printers)}
    )


def hosts_of(printers: list[Printer]) -> list[dict[str, object]]:
    """The worker hosts that drive *printers*, with their last heartbeat."""
    from printers.hosts import HEARTBEAT_STALE_SECONDS, WorkerHost, load_figures

    ids = {p.worker_host_id for p in printers if p.worker_host_id}
    hosts = WorkerHost.objects.filter(pk__in=ids).prefetch_related("printer_set")
    return [
        {
            **host.as_dict(),
            "stale_after": HEARTBEAT_STALE_SECONDS,
            "count": len(host.printer_set.all()),
            **dict(zip(("load1", "cpus"), load_figures(host.load), strict=True)),
        }
        for host in hosts
    ]


@login_required
def printer_page(request: HttpRequest, slug: str) -> HttpResponse:
    """One printer: state, job, terminal, queue, chart, controls, connection."""
    printer = get_object_or_404(Printer, slug=slug)
    caller = caller_of_page(request)
    if not caller.can(printer, Role.VIEWER):
        return forbidden(request, f"viewer role needed on printer {slug!r}")
    lines = list(
        ResponseLine.objects.filter(printer=printer).order_by("-seq")[:TERMINAL_LINES]
    )
    lines.reverse()
    newest = ResponseLine.objects.filter(printer=printer).aggregate(m=Max("seq"))["m"]
    jobs = printer_jobs(printer, finished=PANEL_FINISHED)
    context = card(printer, caller) | {
        "lines": lines,
        "last_id": newest or 0,
        "jobs": [j.as_dict() for j in jobs],
        "finished_shown": PANEL_FINISHED,
        "grbl": printer.is_grbl,
        "steps": ["0.1", "1", "10", "100"],
    }
    return render(request, "printer.html", context)


@login_required
def job_page(request: HttpRequest, job_id: int) -> HttpResponse:
    """One job: file facts, progress, and every run of the same file on that printer."""
    job = get_object_or_404(
        Job.objects.select_related("printer", "uploaded_by", "analysis").defer(
            "analysis__result"
        ),
        pk=job_id,
    )
    caller = caller_of_page(request)
    if not caller.can(job.printer, Role.VIEWER):
        return forbidden(request, f"viewer role needed on printer {job.printer.slug!r}")
    runs = Job.objects.filter(printer=job.printer, sha256=job.sha256).order_by("-id")
    data = job.as_dict()
    analysis = data["analysis"]
    return render(
        request,
        "job.html",
        {
            "job": job,
            "data": data,
            "runs": runs,
            "view": job_view(data),
            "analysis": analysis,
            "figures": analysis_figures(analysis) if analysis else {},
        },
    )


@login_required
def resume_page(request: HttpRequest, job_id: int) -> HttpResponse:
    """Resume a stopped run: choose the line or layer, read the preamble, start."""
    from printhost.api.resume import options_of

    job = get_object_or_404(
        Job.objects.select_related("printer", "analysis"), pk=job_id
    )
    caller = caller_of_page(request)
    if not caller.can(job.printer, Role.VIEWER):
        return forbidden(request, f"viewer role needed on printer {job.printer.slug!r}")
    options = options_of(job)
    return render(
        request,
        "resume.html",
        {
            "job": job,
            "options": options,
            "can_operate": caller.can(job.printer, Role.OPERATOR),
        },
    )


@login_required
def account(request: HttpRequest) -> HttpResponse:
    """The user's API keys and the app-key requests waiting for a decision."""
    caller = caller_of_page(request)
    keys = ApiKey.objects.filter(user=request.user).select_related("printer")
    return render(
        request,
        "account.html",
        {"keys": keys.order_by("-id"), "printers": caller.printers(Role.VIEWER)},
    )


@login_required
def history(request: HttpRequest) -> HttpResponse:
    """Every run of the printers the user may view: totals, filters, CSV export."""
    from printhost.history_page import history_context

    context = history_context(caller_of_page(request), request.GET)
    return render(request, "history.html", context)


@login_required
def farm(request: HttpRequest) -> HttpResponse:
    """The farm: its queue, and the printers by worker host and by material."""
    from printhost.access import Forbidden
    from printhost.farm_page import farm_context

    caller = caller_of_page(request)
    try:
        caller.require_farm(Role.VIEWER)
    except Forbidden as error:
        return forbidden(request, f"the farm: {error}")
    return render(request, "farm.html", farm_context(caller))


def denied(request: HttpRequest, exception: Exception | None = None) -> HttpResponse:
    """handler403: Django's own refusals get the styled page too."""
    return forbidden(request, str(exception or "") or "you may not see this page")
