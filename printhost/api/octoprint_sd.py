"""OctoPrint's SD card endpoints: the card's files, print from it, upload to it.

`GET /api/files/sdcard` lists the card as the printer last listed it (origin
`sdcard`); `POST /api/files/sdcard/<name>` with `{"command": "select", "print":
true}` queues a print from the card; `POST /api/files/sdcard` (multipart, as OctoPrint
takes it) stores the file and queues its copy onto the card, printed after with
`print=true`. `GET/POST /api/printer/sd` report the card and list it again.
"""

from __future__ import annotations

from typing import Any

from django.http import HttpRequest, HttpResponse, JsonResponse
from ninja import Router
from ninja.errors import HttpError

from jobs import sdcard
from printhost.api.common import caller_of
from printhost.api.dialects import (
    choose_printer,
    dialect_route,
    json_body,
    truthy,
    upload_from_form,
)
from printhost.api.octoprint import no_content
from printhost.api.octoprint_jobs import dialect_prefix, upload_answer
from printhost.audit import record
from printhost.models import Role

router = Router(tags=["OctoPrint dialect"])


def _card_file(request: HttpRequest, entry: dict[str, Any], prefix: str) -> dict:
    name = str(entry.get("name", ""))
    resource = request.build_absolute_uri(f"{prefix}/api/files/sdcard/{name}")
    return {
        "name": name,
        "display": entry.get("long_name") or name,
        "path": name,
        "type": "machinecode",
        "typePath": ["machinecode", "gcode"],
        "origin": "sdcard",
        "size": entry.get("size"),
        "refs": {"resource": resource},
    }


@dialect_route(router, "GET", "/api/files/sdcard")
def octoprint_sd_files(request: HttpRequest, slug: str | None = None) -> JsonResponse:
    printer = choose_printer(request, slug, Role.VIEWER)
    files = (printer.sd_card or {}).get("files") or []
    prefix = dialect_prefix(slug)
    return JsonResponse({"files": [_card_file(request, f, prefix) for f in files]})


@dialect_route(router, "POST", "/api/files/sdcard")
def octoprint_sd_upload(request: HttpRequest, slug: str | None = None) -> JsonResponse:
    """Multipart `file` (and `print`): stored, then copied onto the card (a job)."""
    printer = choose_printer(request, slug, Role.OPERATOR)
    sdcard.require_card(printer)  # before the upload is stored
    stored = upload_from_form(request, printer, queue=False)
    caller = caller_of(request)
    to_print = truthy(request.POST.get("print"))
    copy = sdcard.queue_sd_upload(
        printer, stored, print_after=to_print, origin=caller.origin,
        user=caller.user if caller.authenticated else None,
    )  # fmt: skip
    record(caller, "sd.upload", printer=printer, job=copy, detail=copy.sd_name)
    info = _card_file(
        request, {"name": copy.sd_name, "size": copy.size_bytes}, dialect_prefix(slug)
    )
    # Not done: the copy is a queued job that takes the link's time.
    return upload_answer("sdcard", info, done=False, select=to_print, to_print=to_print)


@dialect_route(router, "POST", "/api/files/sdcard/{path:filename}")
def octoprint_sd_file_command(
    request: HttpRequest, filename: str, slug: str | None = None
) -> HttpResponse:
    """`{"command": "select", "print": true}` queues a print from the card; a bare
    select changes nothing (printhost prints what is queued, in order)."""
    printer = choose_printer(request, slug, Role.OPERATOR)
    sdcard.require_card(printer)
    body = json_body(request)
    if body.get("command") != "select":
        raise HttpError(400, f"unknown command {body.get('command')!r}; use select")
    name = sdcard.card_name(filename)
    if truthy(body.get("print")):
        caller = caller_of(request)
        job = sdcard.queue_sd_print(
            printer, name, origin=caller.origin,
            user=caller.user if caller.authenticated else None,
        )  # fmt: skip
        record(caller, "sd.print", printer=printer, job=job, detail=name)
    return no_content()


@dialect_route(router, "GET", "/api/printer/sd")
def octoprint_sd_state(request: HttpRequest, slug: str | None = None) -> JsonResponse:
    printer = choose_printer(request, slug, Role.VIEWER)
    return JsonResponse({"ready": sdcard.card_present(printer)})


@dialect_route(router, "POST", "/api/printer/sd")
def octoprint_sd_command(request: HttpRequest, slug: str | None = None) -> HttpResponse:
    """`init` and `refresh` list the card again (M20); `release` is not supported."""
    printer = choose_printer(request, slug, Role.OPERATOR)
    sdcard.require_card(printer)
    command = json_body(request).get("command")
    if command == "release":
        raise HttpError(409, "releasing the card is not supported; eject it")
    if command not in ("init", "refresh"):
        raise HttpError(400, f"unknown command {command!r}; use init or refresh")
    caller = caller_of(request)
    sdcard.list_sd_card(printer, origin=caller.origin)
    record(caller, "sd.list", printer=printer)
    return no_content()
