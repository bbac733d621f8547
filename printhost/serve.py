"""daphne, made safe for big uploads: request bodies stay on disk, not in memory.

Two things make a plain daphne hold an upload in memory, many times over:

1. Twisted, under daphne, parses every `multipart/form-data` POST into its own
   `request.args` before daphne sees the request: it reads the whole body into
   memory and splits it with the `email` parser. daphne never uses those args (it
   hands the raw body to Django), yet a 64 MB slicer upload peaked at 730 MB.
   Twisted has a switch for this (`parsePOSTFormSubmission`); daphne's requests
   are built here with it off.
2. daphne hands a request to the application only once the whole body has
   arrived, and then queues every chunk of it at once on the application's input
   queue. Here that queue keeps at most `HELD_BYTES` of body in memory and writes
   the rest to a temporary file, reading each chunk back when Django asks for it.
   Only the queue's class changes: `asyncio.Queue` keeps its items through `_put`
   and `_get`, the hooks its own subclasses (`PriorityQueue`, `LifoQueue`) use.

Twisted itself keeps a big body in a temporary file while it arrives, and Django
spools it to another, so an upload's size never shows in the server's memory.

3. Nothing is read or stored for a body that will be refused: `GatedChannel` asks
   `printhost.bodylimits` once a request's headers are in. A body over its cap gets
   413 (at once from Content-Length, else as the cap is crossed); an upload without
   a valid API key or session gets 401 before its body is read (its
   `Expect: 100-continue` is answered only after that check, where Twisted would
   answer it at once), one that does not fit the job storage 507, one past the
   user's uploads in flight 429. A refused request's body file is closed (deleted),
   the connection stops reading and is closed a few seconds later (`printhost.bodygate`).

Access log lines have credentials in query strings redacted (`printhost.redact`).
These patches lean on Twisted's and daphne's internals: `INTERNALS` lists them, and
the server refuses to start when one is missing (Twisted is pinned in requirements).

Run as `python -m printhost.serve` with daphne's own arguments (runhost does).
"""

from __future__ import annotations

import asyncio
import logging
import os
import sys
import tempfile
from importlib.metadata import version
from typing import IO, Any

import daphne.server
from daphne.cli import CommandLineInterface
from daphne.http_protocol import HTTPFactory, WebRequest
from daphne.server import Server
from twisted.web import http

from printhost import logformat, startup
from printhost.bodygate import GatedChannel, RawBodyRequest
from printhost.redact import redact_target

logger = logging.getLogger("printhost.serve")

#: Body bytes an HTTP request may hold in memory while the application reads it.
HELD_BYTES = 1024 * 1024


class SpooledBodyQueue(asyncio.Queue):
    """An application's input queue that moves request bodies past HELD_BYTES to disk."""

    _held: int
    _spool: IO[bytes] | None

    def become_spooled(self) -> None:
        self._held = 0
        self._spool = None

    def _put(self, item: Any) -> None:
        body = item.get("body") if isinstance(item, dict) else None
        if body and item.get("type") == "http.request":
            if self._held + len(body) > HELD_BYTES:
                if self._spool is None:
                    # Lives as long as the request; closed after its last chunk.
                    self._spool = tempfile.TemporaryFile(prefix="printhost-body-")  # noqa: SIM115
                self._spool.seek(0, 2)
                where = (self._spool.tell(), len(body))
                self._spool.write(body)
                item = {**item, "body": b"", "spooled": where}
            else:
                self._held += len(body)
        super()._put(item)

    def _get(self) -> Any:
        item = super()._get()
        if not isinstance(item, dict) or item.get("type") != "http.request":
            return item
        where = item.pop("spooled", None)
        if where is not None and self._spool is not None:
            offset, length = where
            self._spool.seek(offset)
            item["body"] = self._spool.read(length)
        else:
            self._held -= len(item.get("body") or b"")
        if not item.get("more_body") and self._spool is not None:
            self._spool.close()
            self._spool = None
        return item


class RawBodyHTTPFactory(HTTPFactory):
    """daphne's HTTP factory, building `GatedChannel`s of `RawBodyRequest`s."""

    def protocol(self) -> Any:
        return http._GenericHTTPChannelProtocol(GatedChannel())

    def buildProtocol(self, addr: Any) -> Any:
        protocol = super().buildProtocol(addr)
        if protocol is not None:
            protocol.requestFactory = RawBodyRequest
        return protocol


class RedactedAccessLog:
    """daphne's access log, with credentials in query strings redacted."""

    def __init__(self, log: Any) -> None:
        self.log = log

    def __call__(self, protocol: str, action: str, details: dict[str, Any]) -> None:
        if isinstance(details.get("path"), str):
            details = {**details, "path": redact_target(details["path"])}
        self.log(protocol, action, details)


class SpoolingServer(Server):
    """daphne's server; HTTP requests get a `SpooledBodyQueue`, the access log is
    redacted, and the development secret key may not serve beyond loopback."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        from django.conf import settings

        endpoints = kwargs.get("endpoints") or []
        refusal = startup.secret_key_refusal(
            secret_key=settings.SECRET_KEY, debug=settings.DEBUG, hosts=(),
            endpoints=endpoints,
        )  # fmt: skip
        if refusal:
            sys.exit(f"printhost: {refusal}")
        if kwargs.get("action_logger") is not None:
            # In JSON log mode the access log goes through logging (logformat).
            logged = logformat.access_log(kwargs["action_logger"])
            kwargs["action_logger"] = RedactedAccessLog(logged)
        super().__init__(*args, **kwargs)

    def create_application(self, protocol: Any, scope: dict[str, Any]) -> Any:
        queue = super().create_application(protocol, scope)
        if queue is not None and scope.get("type") == "http":
            queue.__class__ = SpooledBodyQueue
            queue.become_spooled()
        return queue


class SpoolingCommandLine(CommandLineInterface):
    server_class = SpoolingServer


#: Every attribute of Twisted, daphne and asyncio this module overrides or reads.
INTERNALS = (
    startup.Internal(daphne.server, "HTTPFactory"),
    startup.Internal(Server, "create_application"),
    startup.Internal(Server, "__init__"),
    startup.Internal(CommandLineInterface, "server_class"),
    startup.Internal(CommandLineInterface, "entrypoint"),
    startup.Internal(HTTPFactory, "buildProtocol"),
    startup.Internal(HTTPFactory, "protocol"),
    startup.Internal(WebRequest, "handleContentChunk"),
    startup.Internal(WebRequest, "gotLength"),
    startup.Internal(WebRequest, "notifyFinish"),
    startup.Internal(WebRequest, "parseCookies"),
    startup.Internal(http.Request, "received_cookies", set_in="__init__"),
    startup.Internal(http.Request, "_parsePOSTFormSubmission", set_in="__init__"),
    startup.Internal(http, "_GenericHTTPChannelProtocol"),
    startup.Internal(http.HTTPChannel, "allHeadersReceived"),
    startup.Internal(http.HTTPChannel, "allContentReceived"),
    startup.Internal(http.HTTPChannel, "checkPersistence"),
    startup.Internal(http.HTTPChannel, "_send100Continue"),
    startup.Internal(http.HTTPChannel, "requests", set_in="__init__"),
    startup.Internal(http.HTTPChannel, "length", set_in="_maybeChooseTransferDecoder"),
    startup.Internal(http.HTTPChannel, "_command", set_in="lineReceived"),
    startup.Internal(http.HTTPChannel, "_path", set_in="lineReceived"),
    startup.Internal(http.HTTPChannel, "_version", set_in="lineReceived"),
    startup.Internal(asyncio.Queue, "_put"),
    startup.Internal(asyncio.Queue, "_get"),
)


def versions() -> str:
    return f"Twisted {version('twisted')}, daphne {version('daphne')}"


def check_internals(internals: tuple[startup.Internal, ...] = INTERNALS) -> None:
    """Exit with a clear message when one of *internals* is gone."""
    refusal = startup.internals_refusal(internals, versions())
    if refusal:
        sys.exit(f"printhost: {refusal}")


#: Connections the web server keeps to PostgreSQL (`PRINTHOST_DB_POOL_SIZE` in
#: printhost/settings.py): it answers each request on a thread of its own.
WEB_POOL_SIZE = 20


def main() -> None:
    check_internals()
    os.environ.setdefault("PRINTHOST_DB_POOL_SIZE", str(WEB_POOL_SIZE))
    # daphne's Server.run() builds its HTTP factory by this module-level name.
    daphne.server.HTTPFactory = RawBodyHTTPFactory
    SpoolingCommandLine.entrypoint()


if __name__ == "__main__":
    main()
