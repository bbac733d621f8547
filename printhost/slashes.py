"""Doubled slashes in a request's path are read as one.

Some clients build URLs as `base + "/" + path` on a base that already ends with
a slash (pyoctoprintapi, which Home Assistant's OctoPrint integration uses, asks
for `/p/mk3//api/printer/bed`); OctoPrint's server takes those. Collapsing slashes
only ever joins path parts, so it can never reach a path outside the one asked.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Callable

    from django.http import HttpRequest, HttpResponse

_SLASHES = re.compile(r"/{2,}")


class CollapseSlashesMiddleware:
    def __init__(self, get_response: Callable[[HttpRequest], HttpResponse]) -> None:
        self.get_response = get_response

    def __call__(self, request: HttpRequest) -> HttpResponse:
        if "//" in request.path_info:
            request.path_info = _SLASHES.sub("/", request.path_info)
            request.path = _SLASHES.sub("/", request.path)
        return self.get_response(request)
