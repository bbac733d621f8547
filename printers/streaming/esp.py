"""Parsing `[ESP700]` and `[ESP701]`, ESP3D's stream commands, and shaping their replies.

    [ESP700]stream=/sd/file.gco    file stream -> stream queue (interruptible)
    [ESP700]/sd/file.gco           file script -> script queue (runs to its end)
    [ESP701]action=PAUSE|RESUME|ABORT [json=yes]
    [ESP701]action=CLEAR_ERROR     forget the last stream error
    [ESP701] [json=yes]            status of the active stream

`/sd/` and `/fs/` both name the printer's job storage. Pure functions: the worker does
the I/O the parsed request asks for.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass

from printers.streaming.streams import StreamType

_ESP = re.compile(r"^\[ESP(?P<number>\d+)\](?P<args>.*)$")
_ACTIONS = {"PAUSE", "RESUME", "ABORT", "CLEAR_ERROR"}


class EspError(ValueError):
    """The command is malformed; the message is the reply for the client."""


@dataclass(frozen=True, slots=True)
class EspFileRequest:
    """[ESP700]: stream or run a stored file."""

    type: StreamType
    path: str
    as_json: bool


@dataclass(frozen=True, slots=True)
class EspStreamControl:
    """[ESP701]: control the stream queue's head, or ask its status (action "")."""

    action: str
    as_json: bool


EspRequest = EspFileRequest | EspStreamControl


def is_esp_command(text: str) -> bool:
    return text.startswith("[ESP")


def parse_esp(text: str) -> EspRequest:
    """Parse one `[ESPxxx]` line; raise EspError with a client-facing message."""
    match = _ESP.match(text.strip())
    if match is None:
        raise EspError(f"not an ESP command: {text!r}")
    number = int(match["number"])
    words = match["args"].split()
    options = dict(word.split("=", 1) for word in words if "=" in word)
    flags = [word for word in words if "=" not in word]
    as_json = options.pop("json", "no").lower() in {"yes", "true", "1"}
    if number == 700:
        return _parse_700(options, flags, as_json=as_json)
    if number == 701:
        action = options.pop("action", "").upper()
        if action and action not in _ACTIONS:
            raise EspError(
                f"[ESP701] unknown action {action!r}: use PAUSE, RESUME, ABORT"
            )
        return EspStreamControl(action, as_json)
    raise EspError(f"[ESP{number}] is not supported here; use [ESP700] or [ESP701]")


def _parse_700(
    options: dict[str, str], flags: list[str], *, as_json: bool
) -> EspRequest:
    if "stream" in options:
        path, streaming = options["stream"], True
    elif flags:
        path, streaming = flags[0], False
    else:
        raise EspError("[ESP700] needs a file: [ESP700]stream=/sd/file.gco")
    storage = path.split("/", 2)[1] if path.count("/") >= 2 else ""
    if storage not in {"sd", "fs"}:
        raise EspError(f"[ESP700] {path!r}: the file name must start with /sd/ or /fs/")
    kinds = {
        ("sd", True): StreamType.SD_FILE_STREAM,
        ("fs", True): StreamType.FS_FILE_STREAM,
        ("sd", False): StreamType.SD_FILE_SCRIPT,
        ("fs", False): StreamType.FS_FILE_SCRIPT,
    }
    name = path.split("/", 2)[2]
    if not name or name.startswith("/") or ".." in name.split("/"):
        # The worker resolves the name inside the printer's storage too (symlinks).
        raise EspError(f"[ESP700] {path!r}: not a file name in /{storage}/")
    return EspFileRequest(kinds[storage, streaming], name, as_json)


def esp_reply(
    number: int,
    message: str,
    *,
    as_json: bool,
    ok: bool = True,
    data: dict[str, object] | None = None,
) -> str:
    """Shape a reply the way ESP3D does: plain text, or its JSON envelope."""
    if not as_json:
        return message if ok else f"error: {message}"
    body: dict[str, object] = {"cmd": str(number), "status": "ok" if ok else "error"}
    body["data"] = data if data is not None else message
    return json.dumps(body, separators=(",", ":"))
