"""Reading stored G-code: cleaned commands with byte offsets, and upload sanity checks.

The upload check and the stream read a file through the same `command_of`, so what
passes the check is exactly what the protocol is given, and the protocol never
refuses a line of an accepted file mid-print (printers/protocol F4: printable ASCII
only; GRBL also refuses its realtime characters `?`, `!`, `~` inside a line):

- comments (`;`, `(...)`) are never sent, so any text may sit in them;
- whitespace inside a command (a tab) is sent as a space;
- a message for the display or the host (M117, M118, M0, M1) is sent as ASCII:
  accented letters lose their accents (`Grüße` -> `Grusse`), other characters
  become `?`. A message is for people; a print must not stop over a glyph;
- any other character outside printable ASCII (`G1 X1Ü`, a DEL byte) refuses the
  file at upload, naming the line: its meaning cannot be guessed.
"""

from __future__ import annotations

import hashlib
import re
import unicodedata
from dataclasses import dataclass
from typing import TYPE_CHECKING

from printers.protocol.checksum import clean_line

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

_CHUNK = 1 << 20


class BadGcode(ValueError):
    """The file cannot be a G-code job; the message says why and where."""


@dataclass(frozen=True, slots=True)
class Command:
    """One command of a file: its index among commands and where it ends in the file."""

    index: int
    text: str
    end_offset: int
    line_number: int


@dataclass(frozen=True, slots=True)
class FileFacts:
    size_bytes: int
    line_count: int
    sha256: str
    longest: int


#: Marlin commands whose argument is free text for people (a display, the host).
_MESSAGE = re.compile(r"^M(0|1|117|118)(?![0-9])", re.IGNORECASE)
#: Letters NFKD does not take apart into ASCII.
_SPELLED = {
    "ß": "ss", "æ": "ae", "Æ": "AE", "œ": "oe", "Œ": "OE", "ø": "o", "Ø": "O",
    "ł": "l", "Ł": "L", "đ": "d", "Đ": "D", "þ": "th", "Þ": "Th", "°": "deg",
}  # fmt: skip
_GRBL_REALTIME = "?!~"


def _printable(char: str) -> bool:
    return " " <= char <= "~"


def _ascii_message(text: str) -> str:
    """A message as printable ASCII: accents dropped, the rest `?`."""
    out = []
    for char in text:
        if _printable(char):
            out.append(char)
            continue
        spelled = _SPELLED.get(char)
        if spelled is None:
            plain = unicodedata.normalize("NFKD", char)
            spelled = "".join(c for c in plain if _printable(c)) or "?"
        out.append(spelled)
    return "".join(out)


def command_of(raw: bytes) -> str:
    """The command a raw file line sends: comments out, as the firmware gets it.

    "" for a line with nothing to send. The result may still hold characters the
    firmware cannot take (outside messages); `command_problem` says which.
    """
    text = clean_line(raw.decode("utf-8", "replace"))
    if not text:
        return ""
    text = "".join(" " if char.isspace() else char for char in text)
    if _MESSAGE.match(text):
        text = _ascii_message(text)
    return text


def command_problem(text: str, *, grbl: bool = False) -> str:
    """Why the firmware's protocol would refuse *text* (from `command_of`), or ""."""
    bad = next((char for char in text if not _printable(char)), None)
    if bad is not None:
        if ord(bad) < 0x80:
            what = f"control byte 0x{ord(bad):02x}"
        elif bad == "\ufffd":
            what = "a byte that is not UTF-8 text (is this a binary file?)"
        else:
            what = f"{bad!r} (U+{ord(bad):04X})"
        return (
            f"{what} cannot be sent: the firmware takes printable ASCII only "
            "(comments and M117/M118 messages may hold any text)"
        )
    if grbl:
        realtime = next((char for char in text if char in _GRBL_REALTIME), None)
        if realtime is not None:
            return (
                f"{realtime!r} is a GRBL realtime command: inside a line it would "
                "act at once"
            )
    return ""


def iter_commands(path: Path, *, start_index: int = 0) -> Iterator[Command]:
    """Yield the commands of *path* in order, comments and blank lines skipped.

    Streams the file; never holds it whole. *start_index* skips commands before it.
    """
    offset = 0
    index = 0
    with path.open("rb") as handle:
        for number, raw in enumerate(handle, start=1):
            offset += len(raw)
            text = command_of(raw)
            if not text:
                continue
            if index >= start_index:
                yield Command(index, text, offset, number)
            index += 1


def inspect_file(
    path: Path, *, max_command_length: int = 0, name: str = "", grbl: bool = False
) -> FileFacts:
    """Check that *path* is a printable G-code file and measure it.

    Errors name the file *name* (the name the user gave it), else the path's name.

    1. Read it in chunks, hashing as we go (SHA-256).
    2. Reject NUL bytes and non-ASCII control bytes: a binary file.
    3. Count commands (as `command_of` gives them to the firmware); reject one the
       protocol would refuse (`command_problem`, GRBL's rules when *grbl*) or one
       longer than *max_command_length* (if set).
    4. Reject a file with no command at all.
    """
    name = name or path.name
    if not path.is_file():
        raise BadGcode(f"{name}: no such file")
    digest = hashlib.sha256()
    size = commands = longest = 0
    number = 0
    with path.open("rb") as handle:
        for raw in handle:
            number += 1
            size += len(raw)
            digest.update(raw)
            _check_text(raw, number, name)
            text = command_of(raw)
            if not text:
                continue
            problem = command_problem(text, grbl=grbl)
            if problem:
                raise BadGcode(f"{name} line {number}: {problem}: {text[:40]!r}")
            commands += 1
            longest = max(longest, len(text))
            if max_command_length and len(text) > max_command_length:
                raise BadGcode(
                    f"{name} line {number}: command is {len(text)} characters, "
                    f"the firmware takes at most {max_command_length}: {text[:40]!r}..."
                )
    if commands == 0:
        raise BadGcode(f"{name}: the file holds no G-code command")
    return FileFacts(size, commands, digest.hexdigest(), longest)


#: Control bytes that never appear in G-code text (tab, newlines, form feed do).
_BAD_BYTES = bytes(b for b in range(32) if b not in b"\t\n\r\x0c")
_ALL_BUT_BAD = bytes(b for b in range(256) if b not in _BAD_BYTES)


def _check_text(raw: bytes, number: int, name: str) -> None:
    bad = raw.translate(None, _ALL_BUT_BAD)
    if not bad:
        return
    if b"\x00" in bad:
        raise BadGcode(
            f"{name} line {number}: NUL byte; this is a binary file, not G-code"
        )
    raise BadGcode(
        f"{name} line {number}: control byte 0x{bad[0]:02x}; "
        "this looks like a binary file, not G-code"
    )
