"""Classify one line from Marlin-dialect firmware (Marlin, Prusa, Repetier, RepRap)."""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass
from difflib import SequenceMatcher

from printers.protocol.events import (
    ActionCommand,
    Busy,
    Capability,
    Event,
    FirmwareError,
    FirmwareHalted,
    FirmwareInfo,
    FirmwareMessage,
    FirmwareReset,
    LineKind,
    TemperatureReport,
)

__all__ = [
    "PLAIN_OK",
    "Reply",
    "ReplyKind",
    "parse_response",
    "parse_temperatures",
    "split_merged",
]


class ReplyKind(enum.Enum):
    """What a firmware line means to the sender."""

    #: `ok`, `ok N12 P15 B3` (ADVANCED_OK), Repetier `ok 12`, `ok T:...`.
    OK = "ok"
    #: `Resend: 12`, `Resend:N12`, `rs 12`: the firmware wants line 12 and after again.
    RESEND = "resend"
    #: Repetier `skip 12`: a line it threw away on purpose (after a resend, or seen).
    SKIP = "skip"
    #: `wait`: the firmware is idle and has heard nothing for NO_TIMEOUTS ms.
    WAIT = "wait"
    #: `echo:busy: processing` and friends: alive, the ok will be late.
    BUSY = "busy"
    #: Resend flow: a line arrived out of sequence (or was a leftover of a flush).
    LINE_NUMBER_ERROR = "line_number_error"
    #: Resend flow: a line arrived damaged (checksum, missing `*` or `N`, format).
    CHECKSUM_ERROR = "checksum_error"
    #: kill(), thermal faults, `!!`, `fatal:`: the firmware stopped itself.
    HALT = "halt"
    #: Any other `Error:` line.
    ERROR = "error"
    #: `start`: the firmware booted.
    START = "start"
    #: `//action:<name> <argument>`.
    ACTION = "action"
    #: A temperature report without ok (M155 autoreport, M109/M190 progress).
    TEMPERATURE = "temperature"
    #: M115's `FIRMWARE_NAME:... KEY:value ...` line.
    FIRMWARE_INFO = "firmware_info"
    #: M115's `Cap:NAME:0|1` lines.
    CAPABILITY = "capability"
    #: Any other `echo:` line.
    ECHO = "echo"
    #: Anything else.
    OTHER = "other"


@dataclass(frozen=True, slots=True)
class Reply:
    """One classified firmware line."""

    kind: ReplyKind
    line_kind: LineKind
    text: str
    #: ok/Resend/skip: the line number; resend-flow errors: "Last Line".
    number: int | None = None
    #: ADVANCED_OK `P`: free planner slots.
    planner_free: int | None = None
    #: ADVANCED_OK `B`: free command-queue slots.
    buffer_free: int | None = None
    #: The event this line means for the worker (info lines, ok T:, errors), if any.
    event: Event | None = None

    @property
    def advanced(self) -> bool:
        """True for an ADVANCED_OK reply (`ok ... P<p> B<b>`)."""
        return self.buffer_free is not None


_ACK = LineKind.ACK
_IMPORTANT = LineKind.IMPORTANT
_RESPONSE = LineKind.RESPONSE

#: A plain `ok` (shared: a Reply is never changed).
PLAIN_OK = Reply(ReplyKind.OK, _ACK, "ok")
_WAIT = Reply(ReplyKind.WAIT, _ACK, "wait")

_OK_NUMBER = re.compile(r"N?(-?\d+)$")
_ADVANCED_OK = re.compile(r"(?:N(-?\d+)\s+)?P(\d+)\s+B(\d+)")
# Whole-line matches: a Resend with anything garbled around its number is not
# believed (R9); it counts as a lost Resend (R8).
_RESEND = re.compile(r"(?:resend|rs)\s*:?\s*N?:?\s*(-?\d+)\s*$", re.IGNORECASE)
_SKIP = re.compile(r"skip\s*:?\s*N?(-?\d+)\s*$", re.IGNORECASE)
_TEMPERATURE = re.compile(
    r"(?:^|\s)(T\d*|B|C|P|L)\s*:\s*(-?\d+(?:\.\d*)?)(?:\s*/\s*(-?\d+(?:\.\d*)?))?"
)
_TEMPERATURE_START = re.compile(r"(?:T\d*|B|C)\s*:\s*-?\d")
#: Bytes no firmware prints on purpose: a bootloader's or a waking UART's noise.
_JUNK = re.compile(r"[^\x20-\x7e]")
_INFO_KEY = re.compile(r"(?:^|\s)([A-Z][A-Z0-9_]{2,}):")
_CAPABILITY = re.compile(r"Cap:([A-Za-z0-9_]+):\s*([01])$")

# Line errors in each firmware's wording (wording facts, from their sources):
# Marlin/Prusa `Line Number is not Last Line Number+1, Last Line: <n>`, `checksum
# mismatch, Last Line: <n>`, `No Checksum with line number, Last Line: <n>`,
# Prusa/Marlin 1.x `No Line Number with checksum, Last Line: <n>`; Repetier
# `expected line <n+1> got <m>`, `Wrong checksum`, `Missing checksum`, `Format
# error`. Smoothieware prints none (only `rs N<n+1>`); RepRapFirmware none at all.
_LINE_NUMBER_ERRORS = (
    "line number is not last line number",
    "expected line",
    "line number is not",
)
_CHECKSUM_ERRORS = (
    "checksum mismatch",
    "no checksum with line number",
    "no line number with checksum",
    "wrong checksum",
    "missing checksum",
    "format error",
    "checksum",
    "last line",
    "line number",
)
#: Repetier names the line it wants, the others the last one they have.
_EXPECTED_LINE = re.compile(r"expected line\s*:?\s*(-?\d+)(?:\s+got\b|\s*$)", re.I)
_LAST_LINE_ONLY = re.compile(r"last line\s*:?\s*(-?\d+)\s*$", re.IGNORECASE)
_HALTS = (
    "printer halted",
    "kill() called",
    "printer stopped due to errors",
    "heating failed",
    "thermal runaway",
    "thermal malfunction",
    "maxtemp triggered",
    "mintemp triggered",
    ", system stopped! heater_id:",
    "kill caused",
    "watchdog barked",
)


#: Starts of replies that may follow an `ok` whose line end noise took away.
_AFTER_OK = ("ok", "Resend", "rs ", "Error:", "echo:", "skip", "wait", "start", "T:")
_TRAILING_OK = re.compile(r"\dok$")
_MID_RESEND = re.compile(r"(?<=\d)(?=Resend:|rs N)")


def split_merged(line: str) -> list[str]:
    """Lines that lost the line end between them, apart again (line noise).

    Only unambiguous joins are split: `okok`, `okResend: 5`, `ok` glued after a
    number (`Resend: 5ok`), and `Resend:` glued after a line error's number.
    """
    text = line.strip()
    if text.startswith("ok "):  # most replies: a space after the ok, so none of below
        return [text]
    parts: list[str] = []
    while text.startswith("ok") and text[2:].startswith(_AFTER_OK):
        parts.append("ok")
        text = text[2:]
    pieces = _MID_RESEND.split(text) if text.startswith("Error:") else [text]
    for piece in pieces:
        if not piece.startswith("ok") and _TRAILING_OK.search(piece):
            parts += [piece[:-2], "ok"]
        else:
            parts.append(piece)
    return parts


def parse_response(line: str) -> Reply:
    """Classify one firmware line (without its newline) into a Reply."""
    if line == "ok":
        return PLAIN_OK
    text = line.strip()
    if text == "ok":
        return PLAIN_OK
    if text.startswith("ok "):
        return _parse_ok(text)
    lower = text.lower()
    if lower.startswith(("resend", "rs ", "rs:")):
        return _parse_numbered(text, _RESEND, ReplyKind.RESEND)
    if lower.startswith("skip"):
        return _parse_numbered(text, _SKIP, ReplyKind.SKIP)
    if text == "wait":
        return _WAIT
    if lower.startswith(("echo:busy:", "busy:")):
        message = text[lower.index("busy:") + 5 :].strip()
        return Reply(ReplyKind.BUSY, _RESPONSE, text, event=Busy(message))
    if lower.startswith("error:"):
        return _parse_error(text, text[6:].strip())
    if garbled := _garbled_flow_line(text, lower):
        return garbled
    if text.startswith("!!") or lower.startswith("fatal:"):
        message = text[2:] if text.startswith("!!") else text[6:]
        return _halt(text, message.strip() or text)
    return _parse_information(text)


def _parse_information(text: str) -> Reply:
    lower = text.lower()
    if "kill() called" in lower or "printer halted" in lower:
        return _halt(text, text)  # the message of an `Error:` split off its line
    if text == "start" or (text.endswith("start") and _JUNK.search(text[:-5])):
        return Reply(ReplyKind.START, _IMPORTANT, text, event=FirmwareReset("start"))
    if text.startswith("//action:"):
        action, _, argument = text[9:].strip().partition(" ")
        event = ActionCommand(action, argument.strip())
        return Reply(ReplyKind.ACTION, _IMPORTANT, text, event=event)
    if text.startswith("FIRMWARE_NAME:"):
        return Reply(
            ReplyKind.FIRMWARE_INFO, _RESPONSE, text, event=_firmware_info(text)
        )
    if text.startswith("Cap:") and (match := _CAPABILITY.match(text)):
        event = Capability(match[1], match[2] == "1")
        return Reply(ReplyKind.CAPABILITY, _RESPONSE, text, event=event)
    if text.startswith("echo:"):
        event = FirmwareMessage(text[5:].strip())
        return Reply(ReplyKind.ECHO, _RESPONSE, text, event=event)
    if _TEMPERATURE_START.match(text) and (readings := parse_temperatures(text)):
        event = TemperatureReport(readings)
        return Reply(ReplyKind.TEMPERATURE, _ACK, text, event=event)
    return Reply(ReplyKind.OTHER, _RESPONSE, text, event=FirmwareMessage(text))


def _parse_ok(text: str) -> Reply:
    rest = text[3:].strip()
    if match := _ADVANCED_OK.match(rest):
        number = int(match[1]) if match[1] is not None else None
        return Reply(
            ReplyKind.OK,
            _ACK,
            text,
            number=number,
            planner_free=int(match[2]),
            buffer_free=int(match[3]),
        )
    if match := _OK_NUMBER.match(rest):
        return Reply(ReplyKind.OK, _ACK, text, number=int(match[1]))
    readings = parse_temperatures(rest) if ":" in rest else {}
    event = TemperatureReport(readings) if readings else None
    return Reply(ReplyKind.OK, _ACK, text, event=event)


def _parse_numbered(text: str, pattern: re.Pattern[str], kind: ReplyKind) -> Reply:
    match = pattern.match(text)
    if match is None:
        return Reply(ReplyKind.OTHER, _RESPONSE, text, event=FirmwareMessage(text))
    return Reply(kind, _IMPORTANT, text, number=int(match[1]))


def _parse_error(text: str, message: str) -> Reply:
    lower = message.lower()
    if any(marker in lower for marker in _HALTS):
        return _halt(text, message)
    resend_kind = None
    if any(marker in lower for marker in _LINE_NUMBER_ERRORS):
        resend_kind = ReplyKind.LINE_NUMBER_ERROR
    elif any(m in lower for m in _CHECKSUM_ERRORS) or _looks_like_line_error(lower):
        resend_kind = ReplyKind.CHECKSUM_ERROR
    elif _JUNK.search(message) and _garbled(message, lower):
        # A garbled line error (line noise on the way back): it cannot be read,
        # so it is a resend-flow error of unknown line, never a fatal one.
        return Reply(ReplyKind.CHECKSUM_ERROR, _IMPORTANT, text)
    if resend_kind is not None:
        return Reply(resend_kind, _IMPORTANT, text, number=_last_line(message))
    event = FirmwareError(message or text)
    return Reply(ReplyKind.ERROR, _IMPORTANT, text, event=event)


_WORDINGS = (
    "line number is not last line number+1, last line:",
    "checksum mismatch, last line:",
    "no checksum with line number, last line:",
    "no line number with checksum, last line:",
    "expected line",
    "wrong checksum",
    "missing checksum",
    "format error",
)


_GARBLED_RESEND = re.compile(r"^\S{2,8}\s*:?\s*N?\d*$")


def _garbled_flow_line(text: str, lower: str) -> Reply | None:
    """A Resend or a line error that line noise misspelt (`R?send: 30`, `Erro:`).

    Its ok still belongs to the error flow, so it is kept as such, without a
    number: a Resend that cannot be read asks for nothing (R9, R8 recover).
    """
    head, colon, rest = lower.partition(":")
    if (
        colon
        and len(head) <= 7
        and SequenceMatcher(None, head, "error").ratio() >= 0.6
        and _looks_like_line_error(rest.strip())
    ):
        return Reply(ReplyKind.CHECKSUM_ERROR, _IMPORTANT, text)
    if _GARBLED_RESEND.match(text) and (
        SequenceMatcher(None, lower.split(":")[0][:6], "resend").ratio() >= 0.6
    ):
        return Reply(ReplyKind.RESEND, _IMPORTANT, text)
    return None


def _garbled(message: str, lower: str) -> bool:
    """Line noise rather than the firmware's own words: a line error once the junk
    is out, or more junk than a firmware's own symbols make (RepRapFirmware's
    heater faults say `1.5°C/sec`: a readable error, and a fatal one)."""
    if _looks_like_line_error(_JUNK.sub("", lower).strip()):
        return True
    return len(_JUNK.findall(message)) * 10 > len(message)


def _looks_like_line_error(lower: str) -> bool:
    """A line error cut short or misspelt by line noise (`Error:ch`, `chexksum`)."""
    words = lower.split(",")[0].strip()
    if not words:
        return True  # `Error:` alone: its message went to the next line
    for wording in _WORDINGS:
        if wording.startswith(words):
            return True
        head = wording.split(",")[0]
        if SequenceMatcher(None, words, head[: len(words) + 2]).ratio() >= 0.75:
            return True
    return False


def _last_line(message: str) -> int | None:
    """The last line the firmware has, from `Last Line: n` or `expected line n+1`."""
    if match := _EXPECTED_LINE.search(message):
        return int(match[1]) - 1
    if match := _LAST_LINE_ONLY.search(message):
        return int(match[1])
    return None


def _halt(text: str, message: str) -> Reply:
    return Reply(ReplyKind.HALT, _IMPORTANT, text, event=FirmwareHalted(message))


def parse_temperatures(text: str) -> dict[str, tuple[float, float | None]]:
    """Readings of a report like `T:210.0 /210.0 B:60.0 /60.0 T0:... @:127 B@:0`.

    Keys are sensors ("T0", "T1", "B", "C", "P", "L"); power (`@:`, `B@:`) and
    M109's `W:` are ignored. A bare "T" becomes "T0" unless T0 is reported too
    (then T is the active tool's copy and is dropped).
    """
    readings: dict[str, tuple[float, float | None]] = {}
    for key, current, target in _TEMPERATURE.findall(text):
        readings[key] = (float(current), float(target) if target else None)
    if "T" in readings:
        active = readings.pop("T")
        readings.setdefault("T0", active)
    return readings


def _firmware_info(text: str) -> FirmwareInfo:
    keys = list(_INFO_KEY.finditer(text))
    fields: dict[str, str] = {}
    for index, match in enumerate(keys):
        end = keys[index + 1].start() if index + 1 < len(keys) else len(text)
        fields[match[1]] = text[match.end() : end].strip()
    name = fields.pop("FIRMWARE_NAME", "")
    return FirmwareInfo(name, fields)
