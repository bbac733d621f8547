"""Reading stored G-code: cleaned commands with byte offsets, and upload sanity checks."""

from __future__ import annotations

import hashlib
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


def iter_commands(path: Path, *, start_index: int = 0) -> Iterator[Command]:
    """Yield the commands of *path* in order, comments and blank lines skipped.

    Streams the file; never holds it whole. *start_index* skips commands before it.
    """
    offset = 0
    index = 0
    with path.open("rb") as handle:
        for number, raw in enumerate(handle, start=1):
            offset += len(raw)
            text = clean_line(raw.decode("ascii", "replace"))
            if not text:
                continue
            if index >= start_index:
                yield Command(index, text, offset, number)
            index += 1


def inspect_file(
    path: Path, *, max_command_length: int = 0, name: str = ""
) -> FileFacts:
    """Check that *path* is a printable G-code file and measure it.

    Errors name the file *name* (the name the user gave it), else the path's name.

    1. Read it in chunks, hashing as we go (SHA-256).
    2. Reject NUL bytes and non-ASCII control bytes: a binary file.
    3. Count commands; reject a command longer than *max_command_length* (if set).
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
            text = clean_line(raw.decode("ascii", "replace"))
            if not text:
                continue
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
