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

Run as `python -m printhost.serve` with daphne's own arguments (runhost does).
"""

from __future__ import annotations

import asyncio
import tempfile
from typing import IO, Any

import daphne.server
from daphne.cli import CommandLineInterface
from daphne.http_protocol import HTTPFactory, WebRequest
from daphne.server import Server

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


class RawBodyRequest(WebRequest):
    """daphne's request, without Twisted's in-memory parse of form bodies."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._parsePOSTFormSubmission = False


class RawBodyHTTPFactory(HTTPFactory):
    """daphne's HTTP factory, building `RawBodyRequest`s."""

    def buildProtocol(self, addr: Any) -> Any:
        protocol = super().buildProtocol(addr)
        if protocol is not None:
            protocol.requestFactory = RawBodyRequest
        return protocol


class SpoolingServer(Server):
    """daphne's server; HTTP requests get a `SpooledBodyQueue`."""

    def create_application(self, protocol: Any, scope: dict[str, Any]) -> Any:
        queue = super().create_application(protocol, scope)
        if queue is not None and scope.get("type") == "http":
            queue.__class__ = SpooledBodyQueue
            queue.become_spooled()
        return queue


class SpoolingCommandLine(CommandLineInterface):
    server_class = SpoolingServer


def main() -> None:
    # daphne's Server.run() builds its HTTP factory by this module-level name.
    daphne.server.HTTPFactory = RawBodyHTTPFactory
    SpoolingCommandLine.entrypoint()


if __name__ == "__main__":
    main()
