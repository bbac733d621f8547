"""What every API module shares: who is calling, the `{error, data}` envelope, errors.

Every answer of the API is UTF-8 JSON. Success and failure both use Repetier-Server's
envelope, `{"error": "<empty or message>", "data": ...}`, with a real HTTP status on
failure (401 no or bad credentials, 403 not allowed, 404 unknown, 400/409/413/422 bad
input), so a slicer that only reads the status and a host that reads `error` both
understand it. Dialect modules (OctoPrint, Moonraker) answer in their own shapes.
"""

from __future__ import annotations

import json
import logging
from typing import TYPE_CHECKING, Any

from django.db import InterfaceError, OperationalError
from django.http import HttpRequest, HttpResponse, JsonResponse
from django.http.multipartparser import MultiPartParserError
from ninja.errors import AuthenticationError, HttpError, ValidationError
from ninja.security.base import AuthBase
from ninja.utils import check_csrf

from jobs.gcode import BadGcode
from jobs.listing import FINISHED_MOST, FINISHED_SHOWN
from jobs.models import Job
from jobs.sdcard import BadCardName, SdRefused
from jobs.services import ChecksumMismatch, FileRemoved
from printers.models import Printer
from printhost.access import Caller, Forbidden, NotAuthenticated, caller_from_request
from printhost.errors import DATABASE_AWAY, RETRY_AFTER_SECONDS

if TYPE_CHECKING:
    from collections.abc import Collection, Mapping

log = logging.getLogger("printhost.api")

SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})


def envelope(data: Any = None, error: str = "", *, status: int = 200) -> JsonResponse:
    """Repetier-Server's answer: `{"error": "...", "data": ...}`."""
    return JsonResponse({"error": error, "data": data}, status=status, safe=False)


class CallerAuth(AuthBase):
    """API key (X-Api-Key, Bearer, ?apikey=) or a logged-in session with CSRF.

    Returns the `Caller`, which views read as `request.auth`. A key that matches
    nobody is a 401 even if a session cookie is present.
    """

    openapi_type = "apiKey"
    openapi_in = "header"
    openapi_name = "X-Api-Key"

    def __call__(self, request: HttpRequest) -> Caller | None:
        caller = caller_from_request(request)
        if not caller.authenticated:
            return None
        # Browser forms: the session cookie alone must not be enough.
        unsafe = caller.key is None and request.method not in SAFE_METHODS
        if unsafe and check_csrf(request) is not None:
            raise HttpError(403, "CSRF check failed: reload the page and try again")
        return caller


def caller_of(request: HttpRequest) -> Caller:
    """The authenticated caller of a view behind `CallerAuth`."""
    caller = getattr(request, "auth", None)
    if not isinstance(caller, Caller):
        caller = caller_from_request(request)
        if not caller.authenticated:
            raise NotAuthenticated("log in or give an API key")
    return caller


def refuse_acting_get(request: HttpRequest, what: str) -> None:
    """A call that changes something, made with GET: only an API-key caller may.

    Repetier-Server's API (and the slicers that speak it) act on GET, so a key may;
    a browser session must POST with a CSRF token, or a link on any page could make
    a logged-in operator's browser heat the hotend (403 otherwise).
    """
    if request.method not in SAFE_METHODS:
        return
    caller = caller_of(request)
    if caller.key is None:
        raise HttpError(
            403,
            f"{what} changes the printer: with a browser session send it as POST "
            "with a CSRF token (GET acts only for API-key callers)",
        )


def printer_for(
    request: HttpRequest,
    slug: str,
    role: int,
    *,
    fields: Collection[str] = (),
) -> Printer:
    """The printer *slug*, if the caller holds *role* on it (404 / 401 / 403).

    *fields*: read only these columns (a view polled often that reads few of a
    printer's sixty; any other is read on first use, a query each).
    """
    caller = caller_of(request)
    found = Printer.objects.only(*fields) if fields else Printer.objects.all()
    try:
        # `get`: the slug is unique, so no ordering (`first` would sort by name).
        printer = found.get(slug=slug)
    except Printer.DoesNotExist:
        raise HttpError(404, f"Unknown printer {slug!r}") from None
    caller.require(printer, role)
    return printer


def job_on(printer: Printer, job_id: int) -> Job:
    """Job *job_id* of *printer*, with its printer and analysis rows (404 if none)."""
    job = (
        Job.objects.filter(printer=printer, pk=job_id)
        .select_related("printer", "analysis")
        .first()
    )
    if job is None:
        raise HttpError(404, f"no job {job_id} on printer {printer.slug!r}")
    return job


def job_of(printer: Printer, params: dict[str, str]) -> Job:
    """The job a call names with `id` (400 without it, 404 if not on *printer*)."""
    job_id = parse_int(params.get("id"), "id", default=-1, minimum=1)
    if job_id < 0:
        raise HttpError(400, "id is required")
    return job_on(printer, job_id)


def json_body(request: HttpRequest) -> dict[str, Any]:
    """The request's JSON object body ({} when empty); 400 with a reason otherwise."""
    if not request.body:
        return {}
    try:
        data = json.loads(request.body)
    except (ValueError, UnicodeDecodeError) as error:
        raise HttpError(400, f"the body is not valid JSON: {error}") from None
    if not isinstance(data, dict):
        raise HttpError(400, "the body must be a JSON object")
    return data


def request_params(request: HttpRequest) -> dict[str, str]:
    """Query parameters, plus form fields of a form or multipart POST.

    A raw body (an `append` chunk) is never parsed: only form content types are.
    """
    values = {k: request.GET.get(k, "") for k in request.GET}
    content_type = request.content_type or ""
    if request.method == "POST" and content_type in (
        "multipart/form-data",
        "application/x-www-form-urlencoded",
    ):
        for key in request.POST:
            values.setdefault(key, request.POST.get(key, ""))
    return values


def parse_int(value: str | None, name: str, *, default: int, minimum: int = 0) -> int:
    """An integer parameter, or a 400 that says what was wrong."""
    if value in (None, ""):
        return default
    try:
        number = int(value)
    except ValueError:
        raise HttpError(400, f"{name} must be an integer, not {value!r}") from None
    if number < minimum:
        raise HttpError(400, f"{name} must be {minimum} or more, not {number}")
    return number


def finished_asked(params: Mapping[str, Any]) -> int:
    """How many finished jobs a job list should give (`finished`, 0 to
    FINISHED_MOST), or a 400 that says what was wrong."""
    value = params.get("finished")
    count = parse_int(
        None if value is None else str(value), "finished", default=FINISHED_SHOWN
    )
    if count > FINISHED_MOST:
        raise HttpError(400, f"finished must be {FINISHED_MOST} or less, not {count}")
    return count


def install_error_handlers(api: Any) -> None:
    """Map every error the API can raise to a status and a clear message."""

    def reply(request: HttpRequest, message: str, status: int) -> HttpResponse:
        return envelope(None, message, status=status)

    @api.exception_handler(AuthenticationError)
    def _unauthenticated(request: HttpRequest, exc: Exception) -> HttpResponse:
        response = reply(
            request, "authentication required: log in or give an API key", 401
        )
        response["WWW-Authenticate"] = 'X-Api-Key realm="printhost"'
        return response

    @api.exception_handler(NotAuthenticated)
    def _not_authenticated(request: HttpRequest, exc: Exception) -> HttpResponse:
        response = reply(request, str(exc), 401)
        response["WWW-Authenticate"] = 'X-Api-Key realm="printhost"'
        return response

    @api.exception_handler(Forbidden)
    def _forbidden(request: HttpRequest, exc: Exception) -> HttpResponse:
        return reply(request, str(exc) or "not allowed", 403)

    @api.exception_handler(HttpError)
    def _http_error(request: HttpRequest, exc: HttpError) -> HttpResponse:
        return reply(request, str(exc), exc.status_code)

    @api.exception_handler(ValidationError)
    def _invalid(request: HttpRequest, exc: ValidationError) -> HttpResponse:
        parts = []
        for error in exc.errors:
            where = ".".join(str(p) for p in error.get("loc", ()) if p not in ("body",))
            parts.append(
                f"{where}: {error.get('msg', 'invalid')}"
                if where
                else error.get("msg", "")
            )
        return reply(request, "bad request: " + "; ".join(parts), 422)

    @api.exception_handler(ChecksumMismatch)
    def _checksum(request: HttpRequest, exc: Exception) -> HttpResponse:
        return reply(request, str(exc), 422)

    @api.exception_handler(BadCardName)
    def _bad_card_name(request: HttpRequest, exc: Exception) -> HttpResponse:
        return reply(request, str(exc), 422)

    @api.exception_handler(SdRefused)
    def _no_card(request: HttpRequest, exc: Exception) -> HttpResponse:
        return reply(request, str(exc), 409)

    @api.exception_handler(FileRemoved)
    def _file_removed(request: HttpRequest, exc: Exception) -> HttpResponse:
        return reply(request, str(exc), 410)

    @api.exception_handler(BadGcode)
    def _bad_gcode(request: HttpRequest, exc: Exception) -> HttpResponse:
        status = 413 if "over the limit" in str(exc) else 400
        return reply(request, str(exc), status)

    @api.exception_handler(MultiPartParserError)
    def _bad_multipart(request: HttpRequest, exc: Exception) -> HttpResponse:
        return reply(request, f"the multipart body could not be read: {exc}", 400)

    @api.exception_handler(OperationalError)
    @api.exception_handler(InterfaceError)
    def _database_away(request: HttpRequest, exc: Exception) -> HttpResponse:
        log.error("%s %s: the database is away: %s", request.method, request.path, exc)
        response = reply(request, DATABASE_AWAY, 503)
        response["Retry-After"] = str(RETRY_AFTER_SECONDS)
        return response

    @api.exception_handler(Exception)
    def _unexpected(request: HttpRequest, exc: Exception) -> HttpResponse:
        log.exception("unexpected error in %s %s", request.method, request.path)
        return reply(
            request, f"internal error: {type(exc).__name__}; see the server log", 500
        )


def docs_access(view: Any) -> Any:
    """The schema and docs page need a session or an API key, like everything else."""
    from functools import wraps

    @wraps(view)
    def wrapped(request: HttpRequest, *args: Any, **kwargs: Any) -> HttpResponse:
        try:
            caller = caller_from_request(request)
        except NotAuthenticated as error:
            return envelope(None, str(error), status=401)
        if not caller.authenticated:
            from django.contrib.auth.views import redirect_to_login

            if "text/html" in request.headers.get("Accept", ""):
                return redirect_to_login(request.get_full_path())
            return envelope(
                None, "authentication required: log in or give an API key", 401
            )
        return view(request, *args, **kwargs)

    return wrapped
