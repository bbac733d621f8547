"""MarlinProtocol's handling of each firmware reply (the Replies table in marlin.py).

A mixin: `_handle_line` classifies a line (marlin_responses.parse_response), emits
Received, and hands the reply to the handler of its kind; the handlers only call the
Recovery and the window that MarlinProtocol owns.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Any, ClassVar

from printers.protocol.events import (
    Busy,
    FirmwareReset,
    LineKind,
    Received,
    TemperatureReport,
)
from printers.protocol.marlin_responses import (
    PLAIN_OK,
    Reply,
    ReplyKind,
    parse_response,
)

if TYPE_CHECKING:
    from collections.abc import Callable

    from printers.protocol.marlin import MarlinProtocol

__all__ = ["ReplyHandling"]

#: ADVANCED_OK's reply as Marlin prints it (`_quick_ok`); B, the free command
#: slots, is the second number group.
_ADVANCED_OK_LINE = re.compile(r"ok N(-?\d+) P\d+ B(\d+)")


class ReplyHandling:
    """What each kind of reply does to the sender's state (see marlin.py's rules)."""

    def _handle_line(self: MarlinProtocol, text: str) -> None:
        if self._file_list and not text.startswith("ok"):
            self._file_list = text != "End file list"
            self._events.append(Received(text, LineKind.RESPONSE))
            return
        self._file_list = text == "Begin file list"
        reply = parse_response(text)
        self._events.append(Received(reply.text, reply.line_kind))
        if reply.kind not in (ReplyKind.OK, ReplyKind.RESEND, ReplyKind.SKIP):
            self._recovery.release_held_ok()
        self._HANDLERS.get(reply.kind, ReplyHandling._on_information)(self, reply)
        self._previous = reply

    def _quick_ok(self: MarlinProtocol, text: str) -> bool:
        """`ok` (ping-pong) or `ok N<n> P<p> B<b>` (ADVANCED_OK), the reply to
        nearly every line of a job: handled as `_handle_line` and `_on_ok` would,
        without classifying it first. False (nothing done) for any other line."""
        if text == "ok":
            number = free = None
        else:
            match = _ADVANCED_OK_LINE.fullmatch(text)
            if match is None:
                return False
            number, free = int(match[1]), int(match[2])
        self._file_list = False
        self._events.append(Received(text, LineKind.ACK))
        self._ok(number, free, advanced=free is not None, temperatures=False)
        # What the resend rules ask of the line before a Resend is its kind.
        self._previous = PLAIN_OK
        return True

    def _on_ok(self: MarlinProtocol, reply: Reply) -> None:
        if reply.event is not None:
            self._events.append(reply.event)
        temperatures = isinstance(reply.event, TemperatureReport)
        self._ok(
            reply.number,
            reply.buffer_free,
            advanced=reply.advanced,
            temperatures=temperatures,
        )

    def _ok(
        self: MarlinProtocol,
        number: int | None,
        buffer_free: int | None,
        *,
        advanced: bool,
        temperatures: bool,
    ) -> None:
        self._advanced = self._advanced or advanced
        if buffer_free is not None and not self._recovery.awaiting_ok:
            self._max_b = max(self._max_b, buffer_free)
        self._recovery.ok(number, temperatures=temperatures)

    def _on_resend(self: MarlinProtocol, reply: Reply) -> None:
        self._recovery.resend(reply, self._previous)

    def _on_skip(self: MarlinProtocol, reply: Reply) -> None:
        self._recovery.skip(reply.number)

    def _on_wait(self: MarlinProtocol, reply: Reply) -> None:
        self._recovery.wait(printing=self.printing)

    def _on_busy(self: MarlinProtocol, reply: Reply) -> None:
        event = reply.event
        self._recovery.busy(event.message if isinstance(event, Busy) else "")
        self._on_information(reply)

    def _on_temperature(self: MarlinProtocol, reply: Reply) -> None:
        self._recovery.temperature()
        self._on_information(reply)

    def _on_start(self: MarlinProtocol, reply: Reply) -> None:
        self._events.append(reply.event or FirmwareReset(reply.text))
        self.abandon()

    def _on_halt(self: MarlinProtocol, reply: Reply) -> None:
        self._on_information(reply)
        self.abandon()

    def _on_firmware_info(self: MarlinProtocol, reply: Reply) -> None:
        # T6: RepRapFirmware does not check the line sequence, so a probe could
        # not tell a lost line from a lost ok there.
        if "reprapfirmware" in reply.text.lower().replace(" ", ""):
            self._recovery.prober.probing = False
        self._on_information(reply)

    def _on_information(self: MarlinProtocol, reply: Reply) -> None:
        if reply.event is not None:
            self._events.append(reply.event)

    def _on_resend_error(self: MarlinProtocol, reply: Reply) -> None:
        """Error lines of the resend flow wait for their Resend (R1b, R8)."""
        self._recovery.line_error(reply.number)

    _HANDLERS: ClassVar[dict[ReplyKind, Callable[[Any, Reply], None]]] = {
        ReplyKind.OK: _on_ok,
        ReplyKind.RESEND: _on_resend,
        ReplyKind.SKIP: _on_skip,
        ReplyKind.WAIT: _on_wait,
        ReplyKind.BUSY: _on_busy,
        ReplyKind.TEMPERATURE: _on_temperature,
        ReplyKind.FIRMWARE_INFO: _on_firmware_info,
        ReplyKind.START: _on_start,
        ReplyKind.HALT: _on_halt,
        ReplyKind.LINE_NUMBER_ERROR: _on_resend_error,
        ReplyKind.CHECKSUM_ERROR: _on_resend_error,
    }
