"""The HTTP channel that decides about a request body before reading it.

Used by `printhost.serve` (which explains why); the rules are in
`printhost.bodylimits`, this is their Twisted side: a `Gate` per request, made when
its headers are in, counting its body as it arrives.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from dataclasses import dataclass
from http import HTTPStatus
from typing import Any

from channels.db import database_sync_to_async
from daphne.http_protocol import WebRequest
from twisted.internet import defer, reactor
from twisted.web import http

from printhost import bodylimits
from printhost.redact import redact_target

logger = logging.getLogger("printhost.serve")

#: Seconds a refused connection stays open (not read) so its client reads the answer.
LINGER_SECONDS = 5.0
#: How often (bytes) an upload of unknown length re-checks the free space.
SPACE_CHECK_BYTES = 8 * 1024 * 1024


@dataclass
class Gate:
    """What the server decided about one request's body while its headers were in."""

    upload: bool
    cap: int
    expect_continue: bool
    #: The Content-Length (None for a chunked body).
    length: int | None = None
    received: int = 0
    checked_space_at: int = 0
    #: The credential check is running; the body is held to the small cap meanwhile.
    pending: bool = False
    #: The whole body arrived while the check ran: hand it on once it passes.
    complete: bool = False
    refused: bool = False
    #: Who holds one of `bodylimits.SLOTS` for this upload ("" once given back).
    uploader: str = ""
    #: Why a body over the small cap is refused (403): its sender may upload
    #: nowhere, so the route's other calls (a POSTed `a=list`) are all it may send.
    small_only: str = ""

    def give_back(self) -> None:
        if self.uploader:
            bodylimits.SLOTS.give_back(self.uploader)
            self.uploader = ""


class RawBodyRequest(WebRequest):
    """daphne's request, without Twisted's in-memory parse of form bodies, whose
    body is counted against its gate as it arrives."""

    gate: Gate | None = None

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._parsePOSTFormSubmission = False

    def handleContentChunk(self, data: bytes) -> None:
        gate = self.gate
        if gate is None:
            super().handleContentChunk(data)
            return
        if gate.refused:
            return
        gate.received += len(data)
        cap = (
            min(gate.cap, bodylimits.body_cap(upload=False))
            if gate.pending
            else gate.cap
        )
        if gate.received > cap:
            if gate.small_only:
                self.channel.refuse(self, 403, gate.small_only)
            else:
                self.channel.refuse(self, 413, bodylimits.too_large(upload=gate.upload))
            return
        if gate.upload and gate.received - gate.checked_space_at >= SPACE_CHECK_BYTES:
            gate.checked_space_at = gate.received
            why = bodylimits.storage_refusal(gate.received)
            if why:
                self.channel.refuse(self, 507, why)
                return
        super().handleContentChunk(data)


class GatedChannel(http.HTTPChannel):
    """Twisted's HTTP channel, deciding about a body before reading it (see module)."""

    def allHeadersReceived(self) -> None:
        # Twisted's own steps, without its unconditional `100 Continue`.
        request = self.requests[-1]
        request.parseCookies()
        self.persistent = self.checkPersistence(request, self._version)
        request.gotLength(self.length)
        method = self._command.decode("latin-1")
        target = self._path.decode("latin-1")
        expect = request.requestHeaders.getRawHeaders(b"Expect") or [b""]
        upload = bodylimits.is_upload(method, target)
        gate = request.gate = Gate(
            upload=upload,
            cap=bodylimits.body_cap(upload=upload),
            expect_continue=expect[0].lower() == b"100-continue"
            and self._version == b"HTTP/1.1",
            length=self.length,
        )
        if self.length is not None and self.length > gate.cap:
            self.refuse(request, 413, bodylimits.too_large(upload=gate.upload))
            return
        if not upload:
            self._go_on(request)
            return
        headers = {
            name.decode("latin-1").lower(): values[0].decode("latin-1")
            for name, values in request.requestHeaders.getAllRawHeaders()
        }
        cookies = {
            k.decode("latin-1"): v.decode("latin-1")
            for k, v in request.received_cookies.items()
        }
        given = bodylimits.credentials(target, headers, cookies)
        if not given.given:
            self.refuse(
                request, 401, "authentication required: log in or give an API key"
            )
            return
        gate.pending = True
        self.transport.pauseProducing()
        check = asyncio.ensure_future(
            database_sync_to_async(bodylimits.uploader)(given)
        )
        done = defer.Deferred.fromFuture(check)
        done.addCallbacks(
            lambda found: self._checked(request, found, by_key=bool(given.key)),
            lambda failure: self._check_failed(request, failure),
        )

    def _checked(
        self, request: RawBodyRequest, found: bodylimits.Uploader, *, by_key: bool
    ) -> None:
        gate = request.gate
        if gate is None or gate.refused or self.transport is None:
            return
        if request not in self.requests or request.channel is None:
            return  # the client left while its credentials were checked
        who = found.who
        if who is None:
            why = "invalid or revoked API key" if by_key else "session not logged in"
            self.refuse(request, 401, why)
            return
        if not found.operator:
            gate.small_only = "uploading a job needs the operator role on a printer"
            gate.cap = bodylimits.body_cap(upload=False)
            if gate.length is not None and gate.length > gate.cap:
                self.refuse(request, 403, gate.small_only)
                return
        why = bodylimits.storage_refusal(gate.length or 0)
        if why:
            self.refuse(request, 507, why)
            return
        if not bodylimits.SLOTS.take(who):
            self.refuse(request, 429, bodylimits.SLOTS.busy())
            return
        gate.uploader = who
        request.notifyFinish().addBoth(lambda _: gate.give_back())
        gate.pending = False
        self.transport.resumeProducing()
        self._go_on(request)

    def _check_failed(self, request: RawBodyRequest, failure: Any) -> None:
        logger.error("upload credential check failed: %s", failure.getErrorMessage())
        gate = request.gate
        if gate is None or gate.refused or request.channel is None:
            return
        self.refuse(request, 503, "could not check the credentials; try again")

    def _go_on(self, request: RawBodyRequest) -> None:
        gate = request.gate
        assert gate is not None
        if gate.complete:
            gate.complete = False
            super().allContentReceived()
        elif gate.expect_continue and gate.length != 0:
            self._send100Continue()

    def allContentReceived(self) -> None:
        gate = self.requests[-1].gate if self.requests else None
        if gate is not None and gate.refused:
            return
        if gate is not None and gate.pending:
            gate.complete = True
            return
        super().allContentReceived()

    def refuse(self, request: RawBodyRequest, status: int, message: str) -> None:
        """Answer *status* now, keep nothing of the body, read no more, then close."""
        gate = request.gate
        if gate is not None:
            gate.refused = True
            gate.give_back()
        with contextlib.suppress(Exception):
            request.content.close()
        body = json.dumps({"error": message, "data": None}).encode()
        head = [
            f"HTTP/1.1 {status} {HTTPStatus(status).phrase}",
            "Content-Type: application/json",
            f"Content-Length: {len(body)}",
            "Connection: close",
        ]
        if status == 401:
            head.append('WWW-Authenticate: X-Api-Key realm="printhost"')
        self.transport.write(("\r\n".join(head) + "\r\n\r\n").encode() + body)
        peer = self.transport.getPeer()
        logger.warning(
            "refused %s %s from %s: %s %s",
            getattr(self, "_command", b"?").decode("latin-1"),
            redact_target(getattr(self, "_path", b"?").decode("latin-1")),
            getattr(peer, "host", peer),
            status,
            message,
        )
        self.persistent = False
        self.dataReceived = lambda data: None  # type: ignore[method-assign]
        self.transport.pauseProducing()
        half_close = getattr(self.transport, "loseWriteConnection", None)
        if half_close is not None:
            half_close()
        transport = self.transport
        reactor.callLater(LINGER_SECONDS, transport.abortConnection)
