"""`manage.py serve_metrics --worker-host NAME`: a worker host's own /metrics.

The same Prometheus format as the control plane's `/metrics`, for that host's
printers and its own row (heartbeat, load, workers), read from the shared database
at each scrape. One small single-threaded HTTP server (the standard library's WSGI
server: one scrape at a time, which is all Prometheus sends); it answers
`GET /metrics` only, after the same check as the control plane's
(`PRINTHOST_METRICS_TOKEN` as a Bearer token, or an admin's API key as a Bearer
when no token is set: there are no sessions here), and never reads a body.
"""

from __future__ import annotations

import io
import json
import logging
import signal
import socket
import time
from typing import TYPE_CHECKING, Any
from wsgiref.simple_server import WSGIRequestHandler, WSGIServer, make_server

from django.core.management.base import BaseCommand, CommandError
from django.db import DatabaseError

from printers.hosts import WorkerHost
from printhost.longrunning import close_failed_connections
from printhost.metrics_access import bind_refusal, header_refusal, key_check_refusal
from printhost.metrics_view import scrape

if TYPE_CHECKING:
    from argparse import ArgumentParser
    from collections.abc import Callable, Iterable
    from types import FrameType

logger = logging.getLogger("printhost.metrics")

Headers = list[tuple[str, str]]


def _json(
    status: str, message: str, extra: Headers | None = None
) -> tuple[str, Headers, bytes]:
    """An error answer: {"error": message}."""
    body = json.dumps({"error": message}).encode()
    headers = [("Content-Type", "application/json"), *(extra or [])]
    return status, headers, body


_STATUS = {401: "401 Unauthorized", 403: "403 Forbidden"}


def answer(environ: dict[str, Any], host: str) -> tuple[str, Headers, bytes]:
    """Status, headers and body for one request to the worker host's server."""
    if environ.get("PATH_INFO") != "/metrics":
        return _json("404 Not Found", "this server answers GET /metrics only")
    if environ.get("REQUEST_METHOD") not in ("GET", "HEAD"):
        return _json("405 Method Not Allowed", "GET /metrics", [("Allow", "GET, HEAD")])
    close_failed_connections()
    try:
        refusal = header_refusal(
            environ.get("HTTP_AUTHORIZATION", ""), environ.get("REMOTE_ADDR", "")
        )
        if refusal is not None:
            challenge = [("WWW-Authenticate", 'Bearer realm="printhost metrics"')]
            extra = challenge if refusal.status == 401 else []
            return _json(_STATUS[refusal.status], refusal.message, extra)
        body, content_type = scrape(environ.get("HTTP_ACCEPT", ""), host=host)
    except DatabaseError as error:
        logger.warning("metrics of worker host %s: database error (%s)", host, error)
        # Its details (the database's address, its user) are for the log only:
        # this answer may go to a caller that showed no credentials yet.
        return _json("503 Service Unavailable", "the database is not reachable")
    return "200 OK", [("Content-Type", content_type)], body


def application_for(host: str) -> Callable[..., Iterable[bytes]]:
    """The WSGI application serving worker host *host*'s metrics."""

    def application(
        environ: dict[str, Any], start_response: Callable[..., Any]
    ) -> Iterable[bytes]:
        status, headers, body = answer(environ, host)
        start_response(status, [*headers, ("Content-Length", str(len(body)))])
        return [b"" if environ.get("REQUEST_METHOD") == "HEAD" else body]

    return application


#: A request's line and headers must be in within this many seconds, however
#: slowly they come: the server answers one connection at a time.
REQUEST_SECONDS = 5.0


class _Deadline(io.RawIOBase):
    """A connection's bytes, read until a deadline: each read waits at most what
    is left of it (and at most *step*), so a byte every second cannot hold the
    connection open for ever."""

    def __init__(self, connection: socket.socket, seconds: float, step: float) -> None:
        self._connection, self._step = connection, step
        self._deadline = time.monotonic() + seconds

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        left = self._deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError(f"the request took over {REQUEST_SECONDS:.0f} s")
        self._connection.settimeout(min(left, self._step))
        return self._connection.recv_into(buffer)


class _QuietHandler(WSGIRequestHandler):
    """Requests go to the debug log, not to stderr line by line. A connection that
    sends nothing for `timeout` seconds, or not its whole request within
    REQUEST_SECONDS, is dropped: the server answers one at a time, and a slow one
    would hold off every scrape (and SIGTERM)."""

    timeout = 2.0

    def setup(self) -> None:
        super().setup()
        self.rfile = io.BufferedReader(
            _Deadline(self.connection, REQUEST_SECONDS, self.timeout)
        )

    def handle(self) -> None:
        try:
            super().handle()
        except TimeoutError as error:
            logger.debug("metrics: dropped %s: %s", self.client_address[0], error)

    def log_message(self, format: str, *args: Any) -> None:
        logger.debug("metrics scrape from %s: " + format, self.client_address[0], *args)


class _Server6(WSGIServer):
    address_family = socket.AF_INET6


class Command(BaseCommand):
    help = "Serve a worker host's Prometheus metrics (its printers and its heartbeat)."

    def add_arguments(self, parser: ArgumentParser) -> None:
        parser.add_argument("--worker-host", metavar="NAME", required=True)
        parser.add_argument("--bind", default="127.0.0.1")
        parser.add_argument("--port", type=int, default=9108)

    def handle(self, *args: Any, **options: Any) -> None:
        name, bind, port = options["worker_host"], options["bind"], options["port"]
        if refusal := bind_refusal(bind) or key_check_refusal():
            raise CommandError(refusal)
        if not WorkerHost.objects.filter(name=name).exists():
            known = ", ".join(WorkerHost.objects.values_list("name", flat=True))
            raise CommandError(
                f"no worker host named {name!r} (known: {known or 'none'}); add it on "
                f"the control plane: manage.py worker_host add {name}"
            )
        server_class = _Server6 if ":" in bind else WSGIServer
        try:
            server = make_server(
                bind, port, application_for(name), server_class, _QuietHandler
            )
        except OSError as error:
            raise CommandError(f"cannot listen on {bind}:{port}: {error}") from None
        address = f"[{bind}]:{port}" if ":" in bind else f"{bind}:{port}"
        WorkerHost.objects.filter(name=name).update(metrics_address=address)
        self.stopping = False
        signal.signal(signal.SIGTERM, self.on_signal)
        signal.signal(signal.SIGINT, self.on_signal)
        self.stdout.write(f"metrics of worker host {name} on http://{address}/metrics")
        self.stdout.flush()
        server.timeout = 0.5
        with server:
            while not self.stopping:
                server.handle_request()

    def on_signal(self, signum: int, frame: FrameType | None) -> None:
        self.stopping = True
