"""Doubled slashes in a request's path are read as one.

Some clients build URLs as `base + "/" + path` on a base that already ends with
a slash (pyoctoprintapi, which Home Assistant's OctoPrint integration uses, asks
for `/p/mk3//api/printer/bed`); OctoPrint's server takes those. Collapsing slashes
only ever joins path parts, so it can never reach a path outside the one asked.

Sync and async, as the chain below it is: under daphne the chain is async, and a
sync-only middleware would have Django hop to a thread and back at it on every
request.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Any

from asgiref.sync import iscoroutinefunction, markcoroutinefunction

if TYPE_CHECKING:
    from collections.abc import Callable

    from django.http import HttpRequest, HttpResponse

_SLASHES = re.compile(r"/{2,}")


def collapse_slashes(
    get_response: Callable[[HttpRequest], Any],
) -> Callable[[HttpRequest], Any]:
    """Middleware: `//` in the path read as `/`."""
    if iscoroutinefunction(get_response):

        async def collapsed_async(request: HttpRequest) -> HttpResponse:
            _collapse(request)
            return await get_response(request)

        return markcoroutinefunction(collapsed_async)

    def collapsed(request: HttpRequest) -> HttpResponse:
        _collapse(request)
        return get_response(request)

    return collapsed


collapse_slashes.sync_capable = True  # type: ignore[attr-defined]
collapse_slashes.async_capable = True  # type: ignore[attr-defined]


def _collapse(request: HttpRequest) -> None:
    if "//" in request.path_info:
        request.path_info = _SLASHES.sub("/", request.path_info)
        request.path = _SLASHES.sub("/", request.path)
