"""Websocket clients of the live feed: one printer (`/ws/printers/<slug>/`) or all.

Each connection is an ESP3D client with a context (a `Caller`): authenticated on
connect (session cookie, or an API key as `?apikey=` / `?token=` / `X-Api-Key` /
`Authorization: Bearer`), refused with close code 4401 (no or bad credentials), 4403
(no viewer role, or a key bound to another printer), 4404 (unknown printer) or 4429
(the user has `PRINTHOST_WS_MAX_PER_USER` feeds open on this server already).

Out: `hello` (state snapshot and the log's last id), `lines`, `state`,
`temperatures`, `job`, `truncated`, `queued`, `reply`, `gone`, `error`. In: `{"cmd": ...}` and
`{"action": ...}` (operator role); on the all-printers feed they name a `printer`.
`?last=<id>` resumes after that id (`0` = everything the log keeps; on the
all-printers feed `?last.<slug>=<id>` per printer), a page (`live.PAGE_LINES`) at
most: further back, a `truncated` notice with `paged: true` says where the feed
starts, and `/printer/response` has the rest; `?filter=<bits>`
hides kinds as Repetier's filter does (8 is never hidden).
"""

from __future__ import annotations

import asyncio
import json
import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from channels.db import database_sync_to_async
from channels.generic.websocket import AsyncJsonWebsocketConsumer

from printers import broadcast, live
from printers.handshake import (
    CLOSE_FORBIDDEN,
    CLOSE_NOT_FOUND,
    Refused,
    caller_from_scope,
    hold_place,
    int_param,
    leave_place,
    query_of,
)
from printers.models import Printer
from printhost.clients import run_action, run_command, wait_reply
from printhost.models import Role

if TYPE_CHECKING:
    from printhost.access import Caller

logger = logging.getLogger("printhost.live")

#: An [ESPxxx] reply is awaited at most this long (s).
REPLY_TIMEOUT = 30.0
ACTIONS = ("pause", "resume", "abort", "bed_clear", "emergency_stop")


@dataclass
class Feed:
    """One printer this connection watches, and where its client is in the log."""

    printer: Printer
    cursor: live.LineCursor
    #: A live batch of lines came since the last reconcile, with no gap before it
    #: left unread: the log holds nothing this client lacks but what followed it.
    heard: bool = False


class LiveConsumer(AsyncJsonWebsocketConsumer):
    """What both feeds share: auth, subscribing, relaying lines, commands."""

    caller: Caller
    feeds: dict[int, Feed]
    #: The place this feed holds among its user's (`hold_place`), once accepted.
    place: int | None = None

    async def connect(self) -> None:
        self.feeds = {}
        self.tasks: set[asyncio.Task[None]] = set()
        await self.accept()
        try:
            query = query_of(self.scope)
            self.filter = int_param(query, "filter") or 0
            printers = await database_sync_to_async(self.identify)()
            starts = {p.pk: int_param(query, self.last_param(p)) for p in printers}
            self.place = hold_place(self.caller)
        except Refused as refused:
            await self.send_json({"type": "error", "message": str(refused)})
            await self.close(code=refused.code)
            return
        for printer in printers:
            await self.subscribe(printer, starts[printer.pk])
        self.spawn(self.reconcile())

    def identify(self) -> list[Printer]:
        """Who the caller is now (`self.caller`) and the printers it may watch, in
        one trip to the database thread, which every client and view of this
        daphne shares."""
        self.caller = caller_from_scope(self.scope)
        return self.printers_to_watch()

    def printers_to_watch(self) -> list[Printer]:
        raise NotImplementedError

    def last_param(self, printer: Printer) -> str:
        """The query parameter holding the last id the client saw of *printer*."""
        raise NotImplementedError

    async def receive(
        self,
        text_data: str | None = None,
        bytes_data: bytes | None = None,
        **kwargs: Any,
    ) -> None:
        """Bad JSON gets an error message, not a dropped connection."""
        try:
            content = json.loads(
                text_data if text_data is not None else bytes_data or b""
            )
        except ValueError:
            await self.send_json({"type": "error", "message": "send JSON objects"})
            return
        await self.receive_json(content)

    async def disconnect(self, code: int) -> None:
        if self.place is not None:
            leave_place(self.place)
            self.place = None
        for task in list(getattr(self, "tasks", ())):
            task.cancel()
        for printer_id in list(getattr(self, "feeds", {})):
            await self.channel_layer.group_discard(
                live.group_for(printer_id), self.channel_name
            )
            await broadcast.unwatch(printer_id)
        self.feeds = {}

    async def subscribe(self, printer: Printer, last: int | None) -> None:
        """Join the printer's group first, then read the database: nothing falls between.

        Without *last* the client starts at the newest line (no history); with it,
        every line after that id is sent first (`0` = all the log keeps).
        """
        await self.channel_layer.group_add(
            live.group_for(printer.pk), self.channel_name
        )
        await broadcast.watch(printer.pk)
        snap = await database_sync_to_async(live.snapshot)(printer.pk)
        start = snap["last"] if last is None else last
        # A page of history at most: a connection must not make the server hold
        # the whole log for a client that may never read it (several such
        # connections ran daphne's memory up by hundreds of MB).
        paged = snap["last"] - start > live.PAGE_LINES
        if paged:
            start = snap["last"] - live.PAGE_LINES
        feed = Feed(printer, live.LineCursor(start, self.filter))
        self.feeds[printer.pk] = feed
        await self.send_json(
            {
                "type": "hello",
                "printer": printer.slug,
                "last": snap["last"],
                "first": snap["first"],
                "state": snap["state"],
                "message": snap["message"],
                "firmware_name": snap["firmware_name"],
                "machine_status": snap["machine_status"],
                "sd_card": snap["sd_card"],
                "temperatures": snap["temperatures"],
                "job": snap["job"],
            }
        )
        if paged:
            await self.send_json(
                {"type": "truncated", "first": start + 1, "paged": True,
                 "printer": printer.slug}
            )  # fmt: skip
        await self.catch_up(feed, None)

    async def catch_up(self, feed: Feed, upto: int | None) -> None:
        """Send the lines after the cursor (up to *upto*) from the database."""
        read = database_sync_to_async(live.lines_after)
        while True:
            lines = await read(feed.printer.pk, feed.cursor.last, upto)
            first = (
                lines[0]["id"] if lines else (upto + 1 if upto is not None else None)
            )
            notice = feed.cursor.truncated(first)
            if notice is not None:
                await self.send_json({**notice, "printer": feed.printer.slug})
            await self.send_lines(feed, feed.cursor.take(lines))
            if len(lines) < live.PAGE_LINES:
                return

    async def reconcile(self) -> None:
        """Now and then, send what the log holds past each cursor.

        A live message that never came (the channel layer is lossy) would otherwise
        leave the client behind until the next message or a reconnect.
        """
        while True:
            await asyncio.sleep(live.RECONCILE_SECONDS)
            try:
                if not await self.recheck():
                    return
                await self.reconcile_feeds()
            except Exception as error:
                # The database away or locked for a moment: the next period
                # tries again. Ending here would leave the client without its
                # lost lines, and its key or role without a check, for good.
                logger.warning("live feed: reconcile failed, next in %s s: %r",
                               live.RECONCILE_SECONDS, error)  # fmt: skip

    async def reconcile_feeds(self) -> None:
        for feed in list(self.feeds.values()):
            # A feed that heard a batch since the last time needs no read: a
            # lost batch before that one showed as a gap and was read then;
            # one lost after it is read next time, unless a later batch shows
            # its gap first. So a lost line still arrives within the period
            # (or two), and a printing printer's hundred watchers cost no
            # reads while its batches come.
            if feed.heard:
                feed.heard = False
            else:
                await self.catch_up(feed, None)

    async def recheck(self) -> bool:
        """Follow changes of keys and roles; False when the connection was closed.

        A revoked key, a session that ended (logout, flushed, expired) or a user
        deactivated, or a lost role closes the connection (4401/4403); on the
        all-printers feed a printer that became visible is added (from its newest
        line) and one that no longer is is dropped with a `gone` message.
        """
        try:
            printers = await database_sync_to_async(self.identify)()
        except Refused as refused:
            await self.send_json({"type": "error", "message": str(refused)})
            await self.close(code=refused.code)
            return False
        wanted = {printer.pk: printer for printer in printers}
        for printer_id in set(self.feeds) - set(wanted):
            feed = self.feeds.pop(printer_id)
            await self.channel_layer.group_discard(
                live.group_for(printer_id), self.channel_name
            )
            await broadcast.unwatch(printer_id)
            message = "you may no longer view this printer"
            await self.send_json(
                {"type": "gone", "printer": feed.printer.slug, "message": message}
            )
        for printer_id in set(wanted) - set(self.feeds):
            await self.subscribe(wanted[printer_id], None)
        return True

    async def send_lines(self, feed: Feed, lines: list[live.Line]) -> None:
        if lines:
            await self.send_json(
                {"type": "lines", "printer": feed.printer.slug, "lines": lines}
            )

    async def live_event(self, message: dict[str, Any]) -> None:
        """A message from the printer's group (the relay or the worker)."""
        feed = self.feeds.get(message["printer_id"])
        if feed is None:
            return
        event = message["event"]
        slug = feed.printer.slug
        if event["type"] == "lines":
            gap = feed.cursor.gap(event["lines"])
            if gap is not None:
                await self.catch_up(feed, gap[1])
            await self.send_lines(feed, feed.cursor.take(event["lines"]))
            feed.heard = True
        else:
            await self.send_json({**event, "printer": slug})

    # -- messages in ------------------------------------------------------------------

    async def receive_json(self, content: Any, **kwargs: Any) -> None:
        if not getattr(self, "feeds", None):
            return
        try:
            if not isinstance(content, dict):
                raise ValueError('send a JSON object: {"cmd": ...} or {"action": ...}')
            feed = self.feed_for(content)
            if "filter" in content:
                bits = content["filter"]
                if not isinstance(bits, int) or bits < 0:
                    raise ValueError("filter must be a whole number >= 0")
                feed.cursor.filter = bits
            elif "cmd" in content:
                await self.command(feed, content["cmd"])
            elif "action" in content:
                await self.action(feed, content["action"])
            else:
                raise ValueError('nothing to do: send {"cmd": ...} or {"action": ...}')
        except (ValueError, PermissionError) as error:
            await self.send_json({"type": "error", "message": str(error)})

    def feed_for(self, content: dict[str, Any]) -> Feed:
        raise NotImplementedError

    async def command(self, feed: Feed, text: Any) -> None:
        if not isinstance(text, str) or not text.strip():
            raise ValueError("cmd must be a non-empty string")
        row = await database_sync_to_async(run_command)(self.caller, feed.printer, text)
        reply = {"type": "queued", "printer": feed.printer.slug, "id": row.pk}
        await self.send_json({**reply, "cmd": row.text})
        if row.text.startswith("[ESP"):
            self.spawn(self.answer(feed, row.pk, row.text))

    async def action(self, feed: Feed, name: Any) -> None:
        """One of ACTIONS, or `prompt:<n>` to answer the printer's dialog."""
        answer = isinstance(name, str) and name.startswith("prompt:")
        if name not in ACTIONS and not answer:
            raise ValueError(
                f"unknown action {name!r}; use one of {', '.join(ACTIONS)}, prompt:<n>"
            )
        audit = {"audit_as": "prompt", "detail": f"button {name[7:]}"} if answer else {}
        row = await database_sync_to_async(run_action)(
            self.caller, feed.printer, name, **audit
        )
        reply = {"type": "queued", "printer": feed.printer.slug, "id": row.pk}
        await self.send_json({**reply, "action": name})

    async def answer(self, feed: Feed, row_id: int, text: str) -> None:
        """ESP3D routing: an [ESPxxx] reply goes to the client that asked, only."""
        reply = await esp_reply(row_id)
        await self.send_json(
            {
                "type": "reply",
                "printer": feed.printer.slug,
                "id": row_id,
                "cmd": text,
                "reply": reply,
            }
        )

    def spawn(self, coroutine: Any) -> None:
        task = asyncio.ensure_future(coroutine)
        self.tasks.add(task)
        task.add_done_callback(self.tasks.discard)


class PrinterConsumer(LiveConsumer):
    """`/ws/printers/<slug>/`: one printer's feed."""

    def printers_to_watch(self) -> list[Printer]:
        slug = self.scope["url_route"]["kwargs"]["slug"]
        printer = Printer.objects.filter(slug=slug).first()
        if printer is None:
            raise Refused(CLOSE_NOT_FOUND, f"unknown printer {slug!r}")
        if not self.caller.can(printer, Role.VIEWER):
            bound = self.caller.bound_printer_id
            if bound is not None and bound != printer.pk:
                raise Refused(
                    CLOSE_FORBIDDEN, "this API key is bound to another printer"
                )
            raise Refused(CLOSE_FORBIDDEN, f"viewer role needed on printer {slug!r}")
        return [printer]

    def last_param(self, printer: Printer) -> str:
        return "last"

    def feed_for(self, content: dict[str, Any]) -> Feed:
        return next(iter(self.feeds.values()))


class PrintersConsumer(LiveConsumer):
    """`/ws/printers/`: every printer the caller may view, each line naming its printer."""

    def printers_to_watch(self) -> list[Printer]:
        return self.caller.printers(Role.VIEWER)

    def last_param(self, printer: Printer) -> str:
        """Ids are per printer: `?last.<slug>=<id>` resumes each one."""
        return f"last.{printer.slug}"

    def feed_for(self, content: dict[str, Any]) -> Feed:
        slug = content.get("printer")
        for feed in self.feeds.values():
            if feed.printer.slug == slug:
                return feed
        raise ValueError(f"name a printer you watch: unknown printer {slug!r}")


async def esp_reply(row_id: int) -> str:
    """The text of the worker's answer to an [ESPxxx] request, or why there is none."""
    answer = await wait_reply(row_id, REPLY_TIMEOUT)
    if answer is None:
        return "error: no reply from the printer's worker (is it running?)"
    return answer["reply"]
