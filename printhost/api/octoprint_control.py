"""OctoPrint's printer control calls, for apps that speak OctoPrint (Home Assistant's
integration through pyoctoprintapi, phone apps): tool, bed and print head.

Each call becomes G-code on the same path as every other client's command
(`run_command`: the operator role, the audit log, 409 while the printer is
offline). As OctoPrint does, moving the head or the extruder is refused with 409
while a job prints, and bad values get 400 with the allowed range.

    POST /api/printer/tool       target, select, extrude, flowrate (GET: temperatures)
    POST /api/printer/bed        target (GET: temperature)
    POST /api/printer/printhead  jog, home, feedrate
"""

from __future__ import annotations

import math
import re
from typing import TYPE_CHECKING, Any

from django.http import HttpRequest, HttpResponse, JsonResponse
from ninja import Router
from ninja.errors import HttpError

from jobs.models import running_job
from printhost.api.common import caller_of
from printhost.api.dialects import choose_printer, dialect_route, json_body
from printhost.api.octoprint import no_content, octoprint_temperatures
from printhost.clients import PrinterOffline, run_command
from printhost.models import Role

if TYPE_CHECKING:
    from printers.models import Printer

router = Router(tags=["OctoPrint dialect"])

_TOOL = re.compile(r"^tool(\d{1,2})$")
#: OctoPrint's own limits for the speed and flow factors (percent).
FEED_FACTOR = (50, 200)
FLOW_FACTOR = (75, 125)


def _number(body: dict[str, Any], key: str, low: float, high: float) -> float:
    value = body.get(key)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise HttpError(400, f"{key} must be a number from {low:g} to {high:g}")
    if not math.isfinite(value) or not low <= value <= high:
        raise HttpError(400, f"{key} must be from {low:g} to {high:g}, not {value!r}")
    return float(value)


def _send(request: HttpRequest, printer: Printer, lines: list[str]) -> HttpResponse:
    try:
        run_command(caller_of(request), printer, "\n".join(lines))
    except PrinterOffline as error:
        raise HttpError(409, str(error)) from None
    return no_content()


def _not_printing(printer: Printer, what: str) -> None:
    job = running_job(printer.pk)
    if job is not None:
        raise HttpError(409, f"{what} while {job.name} is {job.state}")


def _heaters(printer: Printer) -> None:
    if printer.is_grbl:
        raise HttpError(409, f"{printer.slug} runs GRBL, which has no heaters")


def _offsets_refused() -> HttpError:
    return HttpError(
        400,
        "temperature offsets are not supported: printhost sends the targets you set "
        "as they are; set the target you want instead",
    )


@dialect_route(router, "GET", "/api/printer/tool")
def octoprint_tool_state(request: HttpRequest, slug: str | None = None) -> JsonResponse:
    printer = choose_printer(request, slug, Role.VIEWER)
    readings = octoprint_temperatures(printer)
    return JsonResponse({k: v for k, v in readings.items() if k.startswith("tool")})


@dialect_route(router, "POST", "/api/printer/tool")
def octoprint_tool(request: HttpRequest, slug: str | None = None) -> HttpResponse:
    printer = choose_printer(request, slug, Role.OPERATOR)
    body = json_body(request)
    command = body.get("command")
    if command == "target":
        _heaters(printer)
        targets = body.get("targets")
        if not isinstance(targets, dict) or not targets:
            raise HttpError(400, 'targets: {"tool0": <°C>, ...}')
        lines = []
        for name in sorted(targets):
            match = _TOOL.match(str(name))
            if match is None:
                raise HttpError(400, f"{name!r} is not a tool (tool0, tool1, ...)")
            value = _number(targets, name, 0, 450)
            lines.append(f"M104 T{match.group(1)} S{value:g}")
        return _send(request, printer, lines)
    if command == "offset":
        raise _offsets_refused()
    if command == "select":
        match = _TOOL.match(str(body.get("tool", "")))
        if match is None:
            raise HttpError(400, "tool: tool0, tool1, ...")
        _not_printing(printer, "a tool cannot be changed")
        return _send(request, printer, [f"T{match.group(1)}"])
    if command == "extrude":
        _heaters(printer)
        _not_printing(printer, "the extruder cannot be moved")
        amount = _number(body, "amount", -1000, 1000)
        speed = _number(body, "speed", 1, 10000) if "speed" in body else 300.0
        return _send(request, printer, ["G91", f"G1 E{amount:g} F{speed:g}", "G90"])
    if command == "flowrate":
        _heaters(printer)
        factor = _number(body, "factor", *FLOW_FACTOR)
        return _send(request, printer, [f"M221 S{factor:g}"])
    raise HttpError(
        400, f"unknown command {command!r}; use target, select, extrude or flowrate"
    )


@dialect_route(router, "GET", "/api/printer/bed")
def octoprint_bed_state(request: HttpRequest, slug: str | None = None) -> JsonResponse:
    printer = choose_printer(request, slug, Role.VIEWER)
    readings = octoprint_temperatures(printer)
    return JsonResponse({"bed": readings["bed"]} if "bed" in readings else {})


@dialect_route(router, "POST", "/api/printer/bed")
def octoprint_bed(request: HttpRequest, slug: str | None = None) -> HttpResponse:
    printer = choose_printer(request, slug, Role.OPERATOR)
    body = json_body(request)
    command = body.get("command")
    if command == "target":
        _heaters(printer)
        value = _number(body, "target", 0, 200)
        return _send(request, printer, [f"M140 S{value:g}"])
    if command == "offset":
        raise _offsets_refused()
    raise HttpError(400, f"unknown command {command!r}; use target")


@dialect_route(router, "POST", "/api/printer/printhead")
def octoprint_printhead(request: HttpRequest, slug: str | None = None) -> HttpResponse:
    printer = choose_printer(request, slug, Role.OPERATOR)
    body = json_body(request)
    command = body.get("command")
    if command == "jog":
        _not_printing(printer, "the head cannot be jogged")
        words = [
            f"{axis.upper()}{_number(body, axis, -1000, 1000):g}"
            for axis in ("x", "y", "z")
            if axis in body
        ]
        if not words:
            raise HttpError(400, "jog needs x, y or z (mm)")
        speed = _number(body, "speed", 1, 100000) if "speed" in body else 3000.0
        absolute = bool(body.get("absolute", False))
        move = f"{' '.join(words)} F{speed:g}"
        if printer.is_grbl:
            return _send(
                request, printer, [f"$J={'G90' if absolute else 'G91'} {move}"]
            )
        if absolute:
            return _send(request, printer, ["G90", f"G1 {move}"])
        return _send(request, printer, ["G91", f"G1 {move}", "G90"])
    if command == "home":
        _not_printing(printer, "the head cannot be homed")
        axes = body.get("axes")
        if (
            not isinstance(axes, list)
            or not axes
            or not all(str(axis).lower() in ("x", "y", "z") for axis in axes)
        ):
            raise HttpError(400, 'axes: a list of "x", "y" and "z"')
        if printer.is_grbl:
            return _send(request, printer, ["$H"])
        named = " ".join(f"{str(axis).upper()}0" for axis in axes)
        return _send(request, printer, [f"G28 {named}"])
    if command == "feedrate":
        if printer.is_grbl:
            raise HttpError(409, "GRBL changes its feed rate with its override keys")
        factor = _number(body, "factor", *FEED_FACTOR)
        return _send(request, printer, [f"M220 S{factor:g}"])
    raise HttpError(400, f"unknown command {command!r}; use jog, home or feedrate")
