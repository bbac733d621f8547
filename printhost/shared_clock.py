"""Middleware: a web server keeps the database's clock as the time now.

What the pages, the API and the metrics judge by the time now (whether a worker
host is online, a job's elapsed time and ETA) was stamped by other computers on
the database's clock (printers/dbclock.py). A web server on a computer of its
own, a minute off, would show every host offline and every ETA a minute wrong:
before a request, at most once a minute, it reads the database's clock
(`learn_offset_if_due`) so that `shared_now` reckons by it.

Sync and async, like the rest of the chain; under daphne the reading, when due,
goes to the database's thread, and every other request passes straight on.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from asgiref.sync import iscoroutinefunction, markcoroutinefunction, sync_to_async

from printers.dbclock import learn_offset_if_due, offset_due

if TYPE_CHECKING:
    from collections.abc import Callable

    from django.http import HttpRequest, HttpResponse


def learn_clock_offset(
    get_response: Callable[[HttpRequest], Any],
) -> Callable[[HttpRequest], Any]:
    """Middleware: this process's offset from the database's clock, kept fresh."""
    if iscoroutinefunction(get_response):

        async def learning_async(request: HttpRequest) -> HttpResponse:
            if offset_due():
                await sync_to_async(learn_offset_if_due)()
            return await get_response(request)

        return markcoroutinefunction(learning_async)

    def learning(request: HttpRequest) -> HttpResponse:
        learn_offset_if_due()
        return get_response(request)

    return learning


learn_clock_offset.sync_capable = True  # type: ignore[attr-defined]
learn_clock_offset.async_capable = True  # type: ignore[attr-defined]
