"""The raw TCP terminal: ESP3D's telnet client, one listening port per printer.

Any program that opens `socket://host:<terminal_port>` (netcat, a terminal,
Pronterface, another host) is a client. Protocol, one line at a time:

1. the client's first line is an API key; a bad key gets `error: invalid API key` and
   the connection is closed; a key without a viewer role on the printer gets an
   `error: ...` line and is closed too;
2. from then on every response-log line of the printer is written as `<text>\\n`
   (printhost's own notes start with `// printhost:`), filtered by the kinds set with
   `filter <bits>` (Repetier's bits; 8 is never hidden);
3. each line the client sends is a command for the printer, through the same queue
   and permissions as HTTP and websockets (operator role; a viewer gets `error: ...`);
   an `[ESPxxx]` command's reply goes to this client only.

Limits (printers/terminal_admission.py): at most `PRINTHOST_TERMINAL_MAX_CLIENTS`
clients logged in per printer port and `PRINTHOST_TERMINAL_MAX_PER_ADDRESS`
connections per client address (an excess connection gets one `error:` line and is
closed); as many again may wait to log in, the oldest making way for a new one; a
client that gives no key line within `PRINTHOST_TERMINAL_LOGIN_SECONDS` is closed;
a line over MAX_LINE bytes is refused with an `error:` line and discarded up to its
newline without being held (an endless line never grows memory); a command longer
than the printer's firmware takes is refused. Printer output reaches clients with
its control characters removed (tabs kept), so a printer's text cannot drive a
user's terminal.

The feed is the same as the websockets': the printer's channel-layer group, fed by
the worker (Redis) or by this process's relay (no Redis), gaps filled from the log.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import TYPE_CHECKING, Any

from channels.db import database_sync_to_async
from channels.layers import get_channel_layer
from django.conf import settings
from django.db import DatabaseError

from printers import broadcast, live
from printers.consumers import esp_reply
from printers.driver import LinkConfig
from printers.models import Printer
from printers.terminal_admission import Admission
from printers.terminal_text import MAX_LINE, LineReader, TooLong, printable
from printhost.access import Caller, caller_from_key
from printhost.clients import run_command
from printhost.models import ApiKey, Role

if TYPE_CHECKING:
    from collections.abc import Callable

logger = logging.getLogger("printhost.terminal")

#: How often the listeners are matched with the printer table (s).
RESCAN_SECONDS = 5.0
#: A client that takes in none of its output for this long is disconnected: what it
#: does not read piles up, and a session stuck writing to it would no longer see
#: its key revoked (s).
DRAIN_SECONDS = 30.0


class Session:
    """One connected terminal client of one printer; *admit*, asked once its key is
    good, says why it may not stay ("" when it may: `Admission.log_in`)."""

    def __init__(
        self,
        printer: Printer,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        admit: Callable[[Session], str] = lambda session: "",
    ) -> None:
        self.printer = printer
        self.admit = admit
        self.reader = reader
        self.writer = writer
        self.caller: Caller | None = None
        self.cursor = live.LineCursor(0)
        #: A live batch came since the last reconcile (as consumers.Feed.heard).
        self.heard = False
        self.tasks: set[asyncio.Task[None]] = set()
        self.lines = LineReader(reader)
        self.address = peer_address(writer)
        self.command_limit = LinkConfig.from_printer(printer).command_limit

    async def run(self) -> None:
        try:
            if await self.login():
                await self.serve()
        except (
            ConnectionError,
            asyncio.IncompleteReadError,
            asyncio.LimitOverrunError,
        ):
            pass
        finally:
            for task in self.tasks:
                task.cancel()
            self.writer.close()
            with contextlib.suppress(Exception):
                await self.writer.wait_closed()

    async def login(self) -> bool:
        """Read the key line; say why and refuse when it does not give a viewer."""
        try:
            raw = await asyncio.wait_for(
                self.lines.next(), settings.PRINTHOST_TERMINAL_LOGIN_SECONDS
            )
        except TimeoutError:
            await self.say("error: no API key given in time")
            return False
        if raw is None:
            return False
        if isinstance(raw, TooLong):
            await self.say(f"error: key line longer than {MAX_LINE} bytes")
            return False
        key = raw.decode("utf-8", "replace").strip()
        find = database_sync_to_async(caller_from_key)
        caller = await find(key, client="telnet", address=self.address) if key else None
        if caller is None:
            await self.say("error: invalid API key")
            return False
        if not await database_sync_to_async(caller.can)(self.printer, Role.VIEWER):
            await self.say(
                f"error: this key may not watch printer {self.printer.slug!r}"
            )
            return False
        refusal = self.admit(self)
        if refusal:
            await self.say(f"error: {refusal}; try again later")
            return False
        self.caller = caller
        role = await database_sync_to_async(caller.role)(self.printer)
        label = Role(role).name.lower() if role else "none"
        name = getattr(caller.user, "username", "")
        await self.say(f"// printhost: {self.printer.slug} as {name} ({label})")
        return True

    def make_way(self) -> None:
        """Close it while it waits for its key line (A3 in terminal_admission.py)."""
        with contextlib.suppress(Exception):
            self.writer.write(b"error: too many connections waiting to log in\n")
        self.writer.close()

    async def serve(self) -> None:
        """Output and input side by side until the client leaves."""
        layer = get_channel_layer()
        channel = await layer.new_channel()
        group = live.group_for(self.printer.pk)
        await layer.group_add(group, channel)
        await broadcast.watch(self.printer.pk)
        try:
            _, last = await database_sync_to_async(live.log_bounds)(self.printer.pk)
            self.cursor = live.LineCursor(last)
            output = asyncio.ensure_future(self.output(layer, channel))
            commands = asyncio.ensure_future(self.commands())
            reconcile = asyncio.ensure_future(self.reconcile())
            self.tasks |= {output, commands, reconcile}
            done, _ = await asyncio.wait(
                {output, commands, reconcile}, return_when=asyncio.FIRST_COMPLETED
            )
            for task in done:
                if task.exception() is not None and not isinstance(
                    task.exception(), ConnectionError
                ):
                    logger.error("terminal session failed", exc_info=task.exception())
        finally:
            await layer.group_discard(group, channel)
            await broadcast.unwatch(self.printer.pk)

    async def output(self, layer: Any, channel: str) -> None:
        while True:
            message = await layer.receive(channel)
            event = message.get("event", {})
            if event.get("type") != "lines":
                continue
            gap = self.cursor.gap(event["lines"])
            if gap is not None:
                await self.catch_up(gap[1])
            await self.write_lines(self.cursor.take(event["lines"]))
            self.heard = True

    async def reconcile(self) -> None:
        """Now and then, write what the log holds past the cursor (a lost message),
        and end the session when its key was revoked or its role taken away.

        As the websocket feed does (printers/consumers.py): no read while live
        batches come (a lost batch shows as a gap in the next one, one lost after
        the last heard is read next period); a database error is tried again."""
        while True:
            await asyncio.sleep(live.RECONCILE_SECONDS)
            try:
                reason = await database_sync_to_async(self.still_allowed)()
                if reason:
                    await self.say(f"error: {reason}")
                    return
                if self.heard:
                    self.heard = False
                else:
                    await self.catch_up(None)
            except DatabaseError as error:
                logger.warning("terminal: reconcile failed, next in %s s: %r",
                               live.RECONCILE_SECONDS, error)  # fmt: skip

    def still_allowed(self) -> str:
        """Why this session may no longer watch ("" while it may)."""
        caller = self.caller
        if caller is None or caller.key is None:
            return "not logged in"
        key = ApiKey.objects.select_related("user").filter(pk=caller.key.pk).first()
        if key is None or not key.active or not key.user.is_active:
            return "the API key was revoked"
        if not caller.can(self.printer, Role.VIEWER):
            return f"this key may no longer watch printer {self.printer.slug!r}"
        return ""

    async def catch_up(self, upto: int | None) -> None:
        read = database_sync_to_async(live.lines_after)
        while True:
            lines = await read(self.printer.pk, self.cursor.last, upto)
            first = lines[0]["id"] if lines else (None if upto is None else upto + 1)
            if self.cursor.truncated(first) is not None:
                await self.say(f"// printhost: lines before {first} were not kept")
            await self.write_lines(self.cursor.take(lines))
            if len(lines) < live.PAGE_LINES:
                return

    async def write_lines(self, lines: list[live.Line]) -> None:
        if lines:
            text = "".join(f"{printable(line['text'])}\n" for line in lines)
            self.writer.write(text.encode())
            await self.drain()

    async def commands(self) -> None:
        while True:
            raw = await self.lines.next()
            if raw is None:
                return
            if isinstance(raw, TooLong):
                await self.say(f"error: line longer than {MAX_LINE} bytes, discarded")
                continue
            text = raw.decode("utf-8", "replace").strip()
            if text.startswith("[ESP") or len(text) <= self.command_limit:
                if text:
                    await self.command(text)
                continue
            await self.say(
                f"error: command longer than {self.command_limit} characters, "
                "the most this printer's firmware takes; not sent"
            )

    async def command(self, text: str) -> None:
        """One line from the client: `filter <bits>`, or a command for the printer."""
        word, _, rest = text.partition(" ")
        if word.lower() == "filter":
            try:
                self.cursor.filter = int(rest)
            except ValueError:
                await self.say(
                    "error: filter takes a number (1 commands, 2 acks, 4 other)"
                )
            return
        # The key as it is now, not as it was at login: one revoked (or its user
        # deactivated, its role taken) sends nothing more.
        reason = await database_sync_to_async(self.still_allowed)()
        if reason:
            await self.say(f"error: {reason}")
            raise ConnectionError(reason)
        try:
            row = await database_sync_to_async(run_command)(
                self.caller, self.printer, text
            )
        except (PermissionError, ValueError) as error:
            await self.say(f"error: {error}")
            return
        if row.text.startswith("[ESP"):
            task = asyncio.ensure_future(self.answer(row.pk))
            self.tasks.add(task)
            task.add_done_callback(self.tasks.discard)

    async def answer(self, row_id: int) -> None:
        """ESP3D routing: the reply to this client's [ESPxxx] goes to it alone."""
        await self.say(await esp_reply(row_id))

    async def say(self, text: str) -> None:
        self.writer.write(f"{printable(text)}\n".encode())
        await self.drain()

    async def drain(self) -> None:
        """Wait for the client to take in what was written, DRAIN_SECONDS at most
        (ConnectionError then: the session ends)."""
        try:
            await asyncio.wait_for(self.writer.drain(), DRAIN_SECONDS)
        except TimeoutError:
            # Closed at once, its unsent output dropped: a close would wait to send
            # it to a client that reads nothing.
            self.writer.transport.abort()
            raise ConnectionError("the client takes in none of its output") from None


class TerminalServer:
    """Listens on every printer's terminal port; follows the printer table."""

    def __init__(self, bind: str | None = None) -> None:
        self.bind = bind or settings.PRINTHOST_TERMINAL_BIND
        self.servers: dict[str, tuple[int, asyncio.Server]] = {}
        self.admission: Admission[Session] = Admission(
            settings.PRINTHOST_TERMINAL_MAX_CLIENTS,
            settings.PRINTHOST_TERMINAL_MAX_PER_ADDRESS,
        )

    async def run(self, stop: asyncio.Event) -> None:
        try:
            while not stop.is_set():
                await self.rescan()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), RESCAN_SECONDS)
        finally:
            for slug in list(self.servers):
                await self.close(slug)

    async def rescan(self) -> None:
        """Open listeners for new terminal ports, close the ones that went away."""
        wanted = await database_sync_to_async(_wanted)()
        for slug in list(self.servers):
            if self.servers[slug][0] != (wanted.get(slug) or (None,))[0]:
                await self.close(slug)
        for slug, (port, printer) in wanted.items():
            if slug in self.servers:
                continue
            try:
                server = await asyncio.start_server(
                    lambda r, w, p=printer: self.serve_client(p, r, w),
                    self.bind,
                    port,
                    limit=MAX_LINE * 2,
                )
            except OSError as error:
                logger.error(
                    "terminal of %s cannot listen on %s: %s", slug, port, error
                )
                continue
            logger.info("terminal of %s on %s:%s", slug, self.bind, port)
            self.servers[slug] = (port, server)

    async def serve_client(
        self,
        printer: Printer,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
    ) -> None:
        """Run a session for a new connection, or refuse it over a cap, saying why."""
        slug, address = printer.slug, peer_address(writer)
        admission = self.admission
        refusal = admission.refusal(slug, address)
        if refusal:
            logger.warning("terminal of %s refused %s: %s", slug, address, refusal)
            with contextlib.suppress(Exception):
                writer.write(f"error: {refusal}; try again later\n".encode())
                await asyncio.wait_for(writer.drain(), 5)
            writer.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(writer.wait_closed(), 5)
            return
        session = Session(
            printer, reader, writer, admit=lambda s: admission.log_in(slug, s)
        )
        oldest = admission.arrive(slug, address, session)
        if oldest is not None:
            logger.warning(
                "terminal of %s: let go of a connection from %s, still without a "
                "key, for a new one from %s", slug, oldest.address, address,
            )  # fmt: skip
            oldest.make_way()
        try:
            await session.run()
        finally:
            admission.leave(slug, address, session)

    async def close(self, slug: str) -> None:
        _, server = self.servers.pop(slug)
        server.close()
        with contextlib.suppress(Exception):
            await asyncio.wait_for(server.wait_closed(), 2)


def peer_address(writer: asyncio.StreamWriter) -> str:
    peer = writer.get_extra_info("peername")
    return str(peer[0]) if peer else ""


def _wanted() -> dict[str, tuple[int, Printer]]:
    printers = Printer.objects.filter(enabled=True, terminal_port__isnull=False)
    return {p.slug: (p.terminal_port, p) for p in printers}
