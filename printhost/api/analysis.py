"""A job's file analysis: its figures and layers, its thumbnails, asking for it again.

    GET  /printer/analysis/<slug>/<job>          state, figures, layers, objects
    POST /printer/analysis/<slug>/<job>/again    analyse again
    GET  /printer/thumbnail/<slug>/<job>/<name>  one thumbnail (PNG or JPEG)
    GET  /printer/toolpath/<slug>/<job>/<layer>  one layer of the preview's geometry

Thumbnails and toolpaths belong to the file's SHA-256, so they never change:
browsers may keep them a day and revalidate with the ETag. A toolpath layer is
binary (jobs/analysis/toolpath.py's records): a phone fetches the layers it shows,
never the G-code.
"""

from __future__ import annotations

import re

from django.db import transaction
from django.http import FileResponse, HttpRequest, HttpResponse, HttpResponseNotModified
from ninja import Router
from ninja.errors import HttpError

from jobs import analysing
from jobs.models import FileAnalysis, Job
from printhost import audit
from printhost.api.common import caller_of, envelope, job_on, printer_for
from printhost.models import Role

router = Router(tags=["file analysis"])

_THUMBNAIL = re.compile(r"^(\d{1,4})x(\d{1,4})\.(png|jpg)$")
_TYPES = {"png": "image/png", "jpg": "image/jpeg"}


@router.get("/printer/analysis/{slug}/{job_id}", summary="A job's file analysis")
def analysis(request: HttpRequest, slug: str, job_id: int) -> HttpResponse:
    """The analysis's state and figures, with each layer's Z, first command and time."""
    job = job_on(printer_for(request, slug, Role.VIEWER), job_id)
    data = job.analysis_dict()
    if data is None:
        raise HttpError(404, f"job {job_id} has no file to analyse (a print from SD)")
    found = analysing.analysis_of(job)
    if found is not None:
        data["layer_list"] = [
            {"z": layer.z, "line": layer.line, "time": layer.time}
            for layer in found.layers
        ]
        data["notes"] = found.notes
        if found.toolpath and found.kind == "cnc" and found.bbox:
            # One "layer": the whole job seen from above, at its top.
            data["layer_list"] = [{"z": found.bbox[1][2], "line": 0, "time": 0.0}]
        if found.toolpath and found.toolpath["layers"]:
            data["toolpath"] = {
                "features": found.toolpath["features"],
                "bytes": [end - start for start, end in found.toolpath["layers"]],
                "url": f"/printer/toolpath/{slug}/{job.pk}/",
            }
    return envelope(data)


@router.get(
    "/printer/toolpath/{slug}/{job_id}/{layer}",
    summary="One layer of a job's toolpath (binary)",
)
def toolpath(request: HttpRequest, slug: str, job_id: int, layer: int) -> HttpResponse:
    """Layer *layer* (0-based) of the preview's geometry: records of 32-bit words,
    per polyline its first command, kind | feature << 8 | speed << 16, its point
    count, then x, y per point (float32, mm)."""
    job = job_on(printer_for(request, slug, Role.VIEWER), job_id)
    found = analysing.analysis_of(job)
    bounds = (found.toolpath.get("layers") or []) if found is not None else []
    if found is None or not bounds:
        raise HttpError(404, f"job {job_id} has no toolpath (yet)")
    if not 0 <= layer < len(bounds):
        raise HttpError(404, f"job {job_id} has layers 0 to {len(bounds) - 1}")
    start, end = bounds[layer]
    tag = f'"{job.sha256[:16]}-{found.kind}-{layer}-{start}-{end}"'
    if request.headers.get("If-None-Match") == tag:
        answer: HttpResponse = HttpResponseNotModified()
    else:
        path = analysing.toolpath_path(job.sha256, found.kind)
        try:
            with path.open("rb") as handle:
                handle.seek(start)
                body = handle.read(end - start)
        except FileNotFoundError:
            raise HttpError(404, f"job {job_id}: the toolpath is gone") from None
        if len(body) != end - start:
            raise HttpError(404, f"job {job_id}: the toolpath is cut short")
        answer = HttpResponse(body, content_type="application/octet-stream")
    answer["ETag"] = tag
    answer["Cache-Control"] = "private, max-age=86400"
    answer["X-Content-Type-Options"] = "nosniff"
    return answer


@router.post(
    "/printer/analysis/{slug}/{job_id}/again", summary="Analyse a job's file again"
)
def analyse_again(request: HttpRequest, slug: str, job_id: int) -> HttpResponse:
    """Run the analysis again (a failed one, or a pending one whose message may be
    lost: the claim makes a second delivery harmless); 409 while it runs."""
    printer = printer_for(request, slug, Role.OPERATOR)
    job = job_on(printer, job_id)
    if job.analysis_id is None:
        raise HttpError(404, f"job {job_id} has no file to analyse")
    with transaction.atomic():
        again = FileAnalysis.objects.filter(
            pk=job.analysis_id,
            state__in=[
                FileAnalysis.State.FAILED,
                FileAnalysis.State.DONE,
                FileAnalysis.State.PENDING,
            ],
        ).update(state=FileAnalysis.State.PENDING, worker="", reason="", sent_at=None)
        if not again:
            raise HttpError(409, "the analysis is running; wait for it to end")
        pk = job.analysis_id
        transaction.on_commit(lambda: analysing.send(pk))
    audit.record(caller_of(request), "analyse again", printer=printer, job=job)
    return envelope({"job": job.pk, "analysis": "pending"})


@router.get(
    "/printer/thumbnail/{slug}/{job_id}/{name}", summary="A thumbnail of a job's file"
)
def thumbnail(request: HttpRequest, slug: str, job_id: int, name: str) -> HttpResponse:
    job = job_on(printer_for(request, slug, Role.VIEWER), job_id)
    return serve_thumbnail(request, job, name)


def serve_thumbnail(request: HttpRequest, job: Job, name: str) -> HttpResponse:
    """One of *job*'s file's thumbnails (404 for any other name), cached a day."""
    match = _THUMBNAIL.match(name)
    data = job.analysis_dict() or {}
    if match is None or name not in {t["name"] for t in data.get("thumbnails", [])}:
        raise HttpError(404, f"job {job.pk} has no thumbnail {name!r}")
    path = analysing.thumbnail_dir(job.sha256) / name
    if not path.is_file():
        raise HttpError(404, f"thumbnail {name!r} is gone")
    tag = f'"{job.sha256[:16]}-{name}"'
    if request.headers.get("If-None-Match") == tag:
        answer: HttpResponse = HttpResponseNotModified()
    else:
        answer = FileResponse(path.open("rb"), content_type=_TYPES[match.group(3)])
    answer["ETag"] = tag
    answer["Cache-Control"] = "private, max-age=86400"
    answer["X-Content-Type-Options"] = "nosniff"
    return answer


def largest_thumbnail(job: Job) -> str:
    """The name of the job's largest thumbnail, or "" (thumbnails are stored largest
    first)."""
    pictures = (job.analysis_dict() or {}).get("thumbnails") or []
    return pictures[0]["name"] if pictures else ""
