"""handler500: a request that failed because the database is away says so.

While PostgreSQL restarts (or the network to it is cut) every request that reads or
writes fails with a database error. Those get 503 with `Retry-After`, and a message
a client can show, instead of a bare 500: asking again once it is back will work.
Any other unexpected error stays a 500 (Django has already logged its
traceback). Neither answer touches the database, the session or a template.
"""

from __future__ import annotations

import sys

from django.db import InterfaceError, OperationalError
from django.http import HttpRequest, HttpResponse, JsonResponse

#: Seconds a client is asked to wait before it tries again.
RETRY_AFTER_SECONDS = 5

DATABASE_AWAY = "the database is not reachable right now; try again shortly"
INTERNAL = "internal error: the server logged it"


def server_error(request: HttpRequest) -> HttpResponse:
    """Called by Django while the failed request's exception is being handled."""
    error = sys.exc_info()[1]
    away = isinstance(error, OperationalError | InterfaceError)
    status, message = (503, DATABASE_AWAY) if away else (500, INTERNAL)
    if "text/html" in request.headers.get("Accept", ""):
        response: HttpResponse = HttpResponse(
            message, status=status, content_type="text/plain; charset=utf-8"
        )
    else:
        response = JsonResponse({"error": message}, status=status)
    if away:
        response["Retry-After"] = str(RETRY_AFTER_SECONDS)
    return response
