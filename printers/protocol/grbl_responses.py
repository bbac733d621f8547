"""Read one GRBL line: the answer to the oldest line (`ok`, `error:N`) or a push."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

from printers.protocol.events import (
    Alarm,
    Event,
    FirmwareInfo,
    FirmwareMessage,
    FirmwareReset,
    LineKind,
    StatusReport,
)
from printers.protocol.grbl_codes import alarm_meaning, error_meaning
from printers.protocol.grbl_events import (
    BuildOptions,
    CheckMode,
    Locked,
    ProgramEnd,
    Unlocked,
)

if TYPE_CHECKING:
    from collections.abc import Callable

__all__ = ["Answer", "Response", "parse_response", "parse_status"]

# How a line is read; the first row that matches wins.
#
#   line                      | kind      | meaning
#   --------------------------+-----------+-------------------------------------------
#   ok                        | ACK       | Answer(): the oldest line in flight is done
#   error:N                   | IMPORTANT | Answer(failed, N, "error:N <meaning>")
#   <State|KEY:value|...>     | ACK       | StatusReport(state, {KEY: value})
#   Grbl 1.1h ['$' for help]  | IMPORTANT | FirmwareReset(line): GRBL restarted
#   ALARM:N                   | IMPORTANT | Alarm(N, "ALARM:N <meaning>")
#   [VER:1.1h.20190825:info]  | RESPONSE  | FirmwareInfo("Grbl 1.1h.20190825", ...)
#   [OPT:VL,15,128(,3...)]    | RESPONSE  | BuildOptions("VL", 15 blocks, 128 RX bytes)
#   [FIRMWARE:grblHAL]        | RESPONSE  | FirmwareInfo("grblHAL", {FIRMWARE: ...})
#   [MSG:Pgm End]             | RESPONSE  | ProgramEnd(): M2/M30 ran
#   [MSG:Enabled]/[MSG:Disabled] | IMPORTANT | CheckMode(on/off): `$C` toggled
#   [MSG:Caution: Unlocked]   | IMPORTANT | Unlocked(text): `$X` cleared an alarm
#   [MSG:'$H'|'$X' to unlock] | IMPORTANT | Locked(text): started in the alarm lock
#   [MSG:text]                | RESPONSE  | FirmwareMessage(text)
#   anything else: [GC:..] [PRB:..] [HLP:..] [echo:..] $N=v >line:ok
#                             | RESPONSE  | FirmwareMessage(line)
#
# Push messages never answer a line; only `ok` and `error:` do. GRBL 0.9 wrote
# `error: Bad number format` without a number: it still answers, with code None.


@dataclass(frozen=True, slots=True)
class Answer:
    """`ok` or `error:N`: the reply to the oldest unanswered line."""

    failed: bool = False
    #: N of `error:N`; None for `ok` or a 0.9-style `error: <text>`.
    code: int | None = None
    #: "error:N <meaning>" for a failure, "" for ok.
    message: str = ""


@dataclass(frozen=True, slots=True)
class Response:
    """One line read: its response-log kind and what it means."""

    kind: LineKind
    meaning: Answer | Event


def parse_response(line: str) -> Response:
    """Read one whole line (no line ending, not empty) from GRBL."""
    for pattern, read in _READERS:
        match = pattern.match(line)
        if match is not None:
            response = read(line, match)
            if response is not None:
                return response
    return Response(LineKind.RESPONSE, FirmwareMessage(line))


def parse_status(line: str) -> StatusReport | None:
    """`<Idle|MPos:0.000,0.000,0.000|FS:0,0>` -> StatusReport; None if malformed."""
    if len(line) < 3 or line[0] != "<" or line[-1] != ">":
        return None
    state, *parts = line[1:-1].split("|")
    # GRBL 0.9 separated everything with commas: keep its state, drop its fields.
    state = state.split(",", 1)[0]
    if not state:
        return None
    fields = {}
    for part in parts:
        key, _, value = part.partition(":")
        fields[key] = value
    return StatusReport(state, fields)


def _read_ok(line: str, match: re.Match[str]) -> Response:
    return Response(LineKind.ACK, Answer())


def _read_error(line: str, match: re.Match[str]) -> Response:
    detail = match.group(1).strip()
    if _is_number(detail):
        code = int(detail)
        answer = Answer(
            failed=True, code=code, message=f"error:{code} {error_meaning(code)}"
        )
    else:
        answer = Answer(failed=True, message=line)
    return Response(LineKind.IMPORTANT, answer)


def _read_status(line: str, match: re.Match[str]) -> Response | None:
    report = parse_status(line)
    return None if report is None else Response(LineKind.ACK, report)


def _read_banner(line: str, match: re.Match[str]) -> Response:
    return Response(LineKind.IMPORTANT, FirmwareReset(line))


def _read_alarm(line: str, match: re.Match[str]) -> Response:
    detail = match.group(1).strip()
    if _is_number(detail):
        code = int(detail)
        alarm = Alarm(code, f"ALARM:{code} {alarm_meaning(code)}")
    else:
        alarm = Alarm(0, detail or line)
    return Response(LineKind.IMPORTANT, alarm)


def _read_version(line: str, match: re.Match[str]) -> Response:
    version, _, info = match.group(1).partition(":")
    fields = {"VER": version, "INFO": info}
    return Response(LineKind.RESPONSE, FirmwareInfo(f"Grbl {version}", fields))


def _read_options(line: str, match: re.Match[str]) -> Response:
    letters, *numbers = match.group(1).split(",")
    sizes = [int(n) if _is_number(n.strip()) else None for n in numbers[:2]]
    sizes += [None] * (2 - len(sizes))
    options = BuildOptions(letters, sizes[0], sizes[1], {"OPT": match.group(1)})
    return Response(LineKind.RESPONSE, options)


def _read_firmware(line: str, match: re.Match[str]) -> Response:
    name = match.group(1).strip()
    return Response(LineKind.RESPONSE, FirmwareInfo(name, {"FIRMWARE": name}))


#: [MSG:...] texts with a meaning of their own (GRBL 1.1's report.c wording).
_MESSAGES: dict[str, tuple[LineKind, Event]] = {
    "Pgm End": (LineKind.RESPONSE, ProgramEnd()),
    "Enabled": (LineKind.IMPORTANT, CheckMode(enabled=True)),
    "Disabled": (LineKind.IMPORTANT, CheckMode(enabled=False)),
    "Caution: Unlocked": (LineKind.IMPORTANT, Unlocked("Caution: Unlocked")),
    "'$H'|'$X' to unlock": (LineKind.IMPORTANT, Locked("'$H'|'$X' to unlock")),
}


def _read_message(line: str, match: re.Match[str]) -> Response:
    text = match.group(1)
    known = _MESSAGES.get(text.strip())
    if known is not None:
        return Response(*known)
    return Response(LineKind.RESPONSE, FirmwareMessage(text))


if TYPE_CHECKING:
    _Reader = Callable[[str, re.Match[str]], Response | None]

_READERS: tuple[tuple[re.Pattern[str], _Reader], ...] = (
    (re.compile(r"ok$"), _read_ok),
    (re.compile(r"error:(.*)$"), _read_error),
    (re.compile(r"<"), _read_status),
    # "Grbl 1.1h ['$' for help]", also grblHAL's "GrblHAL 1.1f ['$' or '$HELP' ...]".
    (re.compile(r"Grbl\w*\s+v?\d"), _read_banner),
    (re.compile(r"ALARM:(.*)$"), _read_alarm),
    (re.compile(r"\[VER:(.*)\]$"), _read_version),
    (re.compile(r"\[OPT:(.*)\]$"), _read_options),
    (re.compile(r"\[FIRMWARE:(.*)\]$"), _read_firmware),
    (re.compile(r"\[MSG:(.*)\]$"), _read_message),
)


def _is_number(text: str) -> bool:
    """ASCII digits only: str.isdigit() takes "²" too, which int() refuses, and a
    line-noise byte must not stop the worker."""
    return text.isascii() and text.isdigit()
