"""OctoPrint's API, as far as slicers use it (PrusaSlicer, SuperSlicer, OrcaSlicer, Cura).

Answers in OctoPrint's shapes so a slicer's built-in "OctoPrint" host type works with
no plugin. Every path is also served under `/p/<slug>/` to name the printer. A busy
printer queues an upload that asks to print; it never refuses it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from django.contrib.auth import authenticate, login
from django.http import HttpRequest, HttpResponse, JsonResponse
from ninja import Router
from ninja.errors import HttpError

from jobs.sdcard import card_present
from printers.models import Printer
from printhost import __version__, logins
from printhost.access import NotAuthenticated, caller_from_request
from printhost.api.common import caller_of
from printhost.api.dialects import (
    choose_printer,
    dialect_route,
    json_body,
)
from printhost.clients import PrinterOffline, run_action, run_command
from printhost.models import Role

if TYPE_CHECKING:
    from printhost.access import Caller

router = Router(tags=["OctoPrint dialect"])

#: The OctoPrint version we answer like: slicers check only that `text` starts
#: with "OctoPrint"; Cura's plugin wants 1.x features (app keys, select+print).
OCTOPRINT_VERSION = "1.10.3"


def no_content() -> HttpResponse:
    return HttpResponse(status=204)


# -- version, server, login ---------------------------------------------------------


@dialect_route(router, "GET", "/api/version", auth=None)
def octoprint_version(request: HttpRequest, slug: str | None = None) -> JsonResponse:
    """The connection test: anonymous, like OctoPrint's own."""
    return JsonResponse(
        {
            "api": "0.1",
            "server": OCTOPRINT_VERSION,
            "text": f"OctoPrint {OCTOPRINT_VERSION} (printhost {__version__})",
        }
    )


@dialect_route(router, "GET", "/api/server")
def octoprint_server(request: HttpRequest, slug: str | None = None) -> JsonResponse:
    return JsonResponse({"version": OCTOPRINT_VERSION, "safemode": None})


_VIEWER_PERMISSIONS = ["STATUS", "CONNECTION", "WEBCAM", "FILES_LIST", "FILES_DOWNLOAD"]
_OPERATOR_PERMISSIONS = [
    "CONTROL",
    "FILES_UPLOAD",
    "FILES_DELETE",
    "FILES_SELECT",
    "PRINT",
    "GCODE_VIEWER",
    "MONITOR_TERMINAL",
]
_ADMIN_PERMISSIONS = ["ADMIN", "SETTINGS", "SETTINGS_READ", "SYSTEM"]


def _best_role(caller: Caller) -> int | None:
    """The caller's highest role on any printer it may see."""
    roles = [caller.role(p) for p in caller.printers(Role.VIEWER)]
    roles.append(None if caller.key and caller.key.printer_id else caller.role(None))
    return max((r for r in roles if r is not None), default=None)


def _user_info(caller: Caller) -> dict[str, Any]:
    role = _best_role(caller) or 0
    permissions = list(_VIEWER_PERMISSIONS) if role >= Role.VIEWER else []
    if role >= Role.OPERATOR:
        permissions += _OPERATOR_PERMISSIONS
    if role >= Role.ADMIN:
        permissions += _ADMIN_PERMISSIONS
    groups = ["admins", "users"] if role >= Role.ADMIN else ["users"]
    return {
        "name": caller.user.get_username(),
        "active": True,
        "user": True,
        "admin": role >= Role.ADMIN,
        "groups": groups,
        "permissions": permissions,
        "needs": {"role": [p.lower() for p in permissions], "group": groups},
    }


@dialect_route(router, "POST", "/api/login", auth=None)
def octoprint_login(request: HttpRequest, slug: str | None = None) -> JsonResponse:
    """`{"passive": true}`: who the key or session is; `{"user", "pass"}`: log in."""
    body = json_body(request)
    caller = caller_from_request(request)
    if not body.get("passive") and "user" in body:
        if request.content_type != "application/json":
            raise HttpError(415, "send the login as application/json")
        try:
            logins.check(body.get("user"), request)
        except logins.Throttled as error:
            raise HttpError(429, str(error)) from None
        user = authenticate(
            request, username=str(body.get("user")), password=str(body.get("pass"))
        )
        if user is None:
            raise NotAuthenticated("wrong user name or password")
        login(request, user)
        caller = caller_from_request(request)
    if not caller.authenticated:
        raise NotAuthenticated("log in or give an API key")
    info = _user_info(caller)
    info["session"] = request.session.session_key or ""
    info["_is_external_client"] = False
    return JsonResponse(info)


@dialect_route(router, "GET", "/api/currentuser")
def octoprint_current_user(
    request: HttpRequest, slug: str | None = None
) -> JsonResponse:
    info = _user_info(caller_of(request))
    return JsonResponse(
        {
            "name": info["name"],
            "permissions": info["permissions"],
            "groups": info["groups"],
        }
    )


@dialect_route(router, "GET", "/api/settings")
def octoprint_settings(request: HttpRequest, slug: str | None = None) -> JsonResponse:
    """What Cura reads to learn the server's features: no SD card, no webcam."""
    caller_of(request)
    return JsonResponse(
        {
            "api": {"enabled": True, "allowCrossOrigin": False},
            "feature": {"sdSupport": False, "temperatureGraph": True},
            "webcam": {"webcamEnabled": False},
            "plugins": {},
            "gcodeAnalysis": {"runAt": "never"},
        }
    )


@dialect_route(router, "GET", "/api/printerprofiles")
def octoprint_printer_profiles(
    request: HttpRequest, slug: str | None = None
) -> JsonResponse:
    printer = choose_printer(request, slug, Role.VIEWER)
    profile = {
        "id": "_default",
        "name": printer.name,
        "model": printer.firmware_name or printer.firmware,
        "color": "default",
        "current": True,
        "default": True,
        "heatedBed": True,
        "heatedChamber": False,
        "extruder": {"count": 1, "nozzleDiameter": 0.4, "sharedNozzle": False},
        "volume": {"formFactor": "rectangular", "origin": "lowerleft"},
        "resource": request.build_absolute_uri("/api/printerprofiles/_default"),
    }
    return JsonResponse({"profiles": {"_default": profile}})


# -- connection -----------------------------------------------------------------------

_OCTOPRINT_STATE_TEXT = {
    Printer.State.OFFLINE: "Offline",
    Printer.State.CONNECTING: "Connecting",
    Printer.State.IDLE: "Operational",
    Printer.State.PRINTING: "Printing",
    Printer.State.PAUSED: "Paused",
    Printer.State.WAITSTART: "Operational",
    Printer.State.ERROR: "Error",
}


def _state_text(printer: Printer) -> str:
    return _OCTOPRINT_STATE_TEXT.get(printer.state, "Offline")


@dialect_route(router, "GET", "/api/connection")
def octoprint_connection(request: HttpRequest, slug: str | None = None) -> JsonResponse:
    printer = choose_printer(request, slug, Role.VIEWER)
    return JsonResponse(
        {
            "current": {
                "state": _state_text(printer),
                "port": printer.port,
                "baudrate": printer.baud,
                "printerProfile": "_default",
            },
            "options": {
                "ports": [printer.port],
                "baudrates": [printer.baud],
                "printerProfiles": [{"id": "_default", "name": printer.name}],
                "portPreference": printer.port,
                "baudratePreference": printer.baud,
                "printerProfilePreference": "_default",
                "autoconnect": printer.enabled,
            },
        }
    )


@dialect_route(router, "POST", "/api/connection")
def octoprint_connection_command(
    request: HttpRequest, slug: str | None = None
) -> HttpResponse:
    """connect / disconnect: the worker reconnects or lets go of the port."""
    printer = choose_printer(request, slug, Role.OPERATOR)
    command = str(json_body(request).get("command", ""))
    actions = {"connect": "reconnect", "disconnect": "disconnect"}
    if command not in actions:
        raise HttpError(400, f"unknown command {command!r}; use connect or disconnect")
    run_action(
        caller_of(request),
        printer,
        actions[command],
        audit_as=command,
        detail="OctoPrint connection command",
    )
    return no_content()


# -- printer --------------------------------------------------------------------------


def octoprint_temperatures(printer: Printer) -> dict[str, Any]:
    """OctoPrint's `temperature` from the worker's `{"T0": {"current", "target"}}`."""
    names = {"B": "bed", "C": "chamber"}
    found: dict[str, Any] = {}
    for key, reading in (printer.temperatures or {}).items():
        name = names.get(key)
        if name is None and key.startswith("T"):
            name = f"tool{key[1:] or '0'}"
        if name is None or not isinstance(reading, dict):
            continue
        found[name] = {
            "actual": reading.get("current"),
            "target": reading.get("target"),
            "offset": 0,
        }
    return found


def state_and_flags(printer: Printer) -> dict[str, Any]:
    state = printer.state
    operational = state in (
        Printer.State.IDLE,
        Printer.State.PRINTING,
        Printer.State.PAUSED,
        Printer.State.WAITSTART,
    )
    error = state == Printer.State.ERROR
    text = _state_text(printer)
    if state == Printer.State.WAITSTART:
        text = "Operational (waiting for the bed to be cleared)"
    if error and printer.state_message:
        text = f"Error: {printer.state_message}"
    return {
        "text": text,
        "error": printer.state_message if error else "",
        "flags": {
            "operational": operational,
            "printing": state == Printer.State.PRINTING,
            "pausing": False,
            "paused": state == Printer.State.PAUSED,
            "cancelling": False,
            "resuming": False,
            "finishing": False,
            "sdReady": card_present(printer),
            "error": error,
            "ready": state == Printer.State.IDLE,
            "closedOrError": not operational,
        },
    }


@dialect_route(router, "GET", "/api/printer")
def octoprint_printer(request: HttpRequest, slug: str | None = None) -> JsonResponse:
    """Temperatures and state; 409 when the printer is not connected (as OctoPrint)."""
    printer = choose_printer(request, slug, Role.VIEWER)
    if printer.state in (Printer.State.OFFLINE, Printer.State.CONNECTING):
        return JsonResponse({"error": "Printer is not operational"}, status=409)
    return JsonResponse(
        {
            "temperature": octoprint_temperatures(printer),
            "state": state_and_flags(printer),
            "sd": {"ready": card_present(printer)},
        }
    )


@dialect_route(router, "POST", "/api/printer/command")
def octoprint_printer_command(
    request: HttpRequest, slug: str | None = None
) -> HttpResponse:
    """`{"commands": [...]}` or `{"command": "..."}`: queued for the worker."""
    printer = choose_printer(request, slug, Role.OPERATOR)
    body = json_body(request)
    commands = body.get("commands")
    if commands is None and "command" in body:
        commands = [body["command"]]
    if not isinstance(commands, list) or not all(isinstance(c, str) for c in commands):
        raise HttpError(
            400, "send {'commands': [<G-code>, ...]} or {'command': <G-code>}"
        )
    lines = [c.strip() for c in commands if c.strip()]
    if not lines:
        raise HttpError(400, "no command to send")
    try:
        run_command(caller_of(request), printer, "\n".join(lines))
    except PrinterOffline as error:
        raise HttpError(409, str(error)) from None
    except ValueError as error:
        raise HttpError(400, str(error)) from None
    return no_content()
