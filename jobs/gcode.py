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

A stored file is text G-code or Prusa's binary G-code (`.bgcode`, jobs/bgcode.py):
`file_lines` reads either as plain G-code lines, the binary one block by block, so
the check, the stream and the analysis never see the difference. A line's offset is
a position in the stored file (progress is bytes of the stored file); in a binary
file it is interpolated inside the block that holds the line.
"""

from __future__ import annotations

import hashlib
import re
import unicodedata
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, TypeVar, cast

from jobs.bgcode import BadBgcode, BgcodeReader, BlockType, is_bgcode
from printers.protocol.checksum import clean_line, has_own_number

T = TypeVar("T")
C = TypeVar("C")

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from pathlib import Path
    from typing import Any, BinaryIO

_CHUNK = 1 << 20
#: The longest line a stored file may hold (bytes). G-code lines are short; the
#: longest comments (a slicer's settings, a thumbnail's base64) are kilobytes.
MAX_LINE_BYTES = 4 << 20


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
    # Printable ASCII (almost every line) holds no whitespace but the space: the
    # character-by-character pass below is for the rare tab or exotic byte.
    if not (text.isascii() and text.isprintable()):
        text = "".join(" " if char.isspace() else char for char in text)
    if text[0] in "Mm" and _MESSAGE.match(text):
        text = _ascii_message(text)
    return text


def command_problem(text: str, *, grbl: bool = False) -> str:
    """Why the firmware's protocol would refuse *text* (from `command_of`), or ""."""
    # Printable ASCII (almost every line) is refused by nothing but GRBL's rule:
    # the character-by-character search is for the rare line that is not.
    plain = text.isascii() and text.isprintable()
    bad = None if plain else next((c for c in text if not _printable(c)), None)
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
    if not grbl and has_own_number(text):  # GRBL ignores N words
        return (
            "the line carries its own line number: printhost numbers the lines it "
            "sends; remove the N words"
        )
    if grbl:
        realtime = next((char for char in text if char in _GRBL_REALTIME), None)
        if realtime is not None:
            return (
                f"{realtime!r} is a GRBL realtime command: inside a line it would "
                "act at once"
            )
    return ""


def iter_commands(
    path: Path, *, start_index: int = 0, start_offset: int = 0
) -> Iterator[Command]:
    """Yield the commands of *path* in order, comments and blank lines skipped.

    Streams the file; never holds it whole. *start_index* skips commands before it;
    *start_offset*, where that command's line begins in a text file, lets the
    reading seek there instead of reading every line before it (a binary file is
    decoded from its start). Line numbers count from the start offset then.
    """
    # Without a *comment* reader, read_entries yields commands only.
    entries = read_entries(path, start_index=start_index, start_offset=start_offset)
    return cast("Iterator[Command]", entries)


def read_entries(
    path: Path,
    *,
    start_index: int = 0,
    start_offset: int = 0,
    comment: Callable[[bytes], T | None] | None = None,
    command: Callable[[int, str, int], C] | None = None,
) -> Iterator[Command | C | T]:
    """`iter_commands`, with what *comment* makes of the lines that send nothing
    (comments, blank lines) from the start on, where it makes something.

    *command* (index, text, end offset) makes what is yielded for a command in
    place of a Command (the worker's stream makes its Lines so, read once).
    """
    index = 0
    if start_offset > 0 and _seekable_text(path):
        index = start_index
    else:
        start_offset = 0
    lines = file_lines(path, start=start_offset)
    for number, (raw, offset) in enumerate(lines, start=1):
        text = command_of(raw)
        if not text:
            if comment is not None and index >= start_index:
                found = comment(raw)
                if found is not None:
                    yield found
            continue
        if index >= start_index:
            if command is None:
                yield Command(index, text, offset, number)
            else:
                yield command(index, text, offset)
        index += 1


def _seekable_text(path: Path) -> bool:
    with path.open("rb") as handle:
        return not is_bgcode(handle.read(4))


def file_lines(
    path: Path, *, digest: Any = None, name: str = "", start: int = 0
) -> Iterator[tuple[bytes, int]]:
    """The lines of a stored file as plain G-code, each with the offset in the file
    where it ends. *digest* (hashlib) is fed every byte of the stored file; *start*
    (a text file only) is where reading begins.

    A broken binary file raises BadGcode (naming *name*) where the break is found.
    """
    with path.open("rb") as handle:
        binary = is_bgcode(handle.read(4))
        handle.seek(0)
        if binary:
            try:
                yield from _bgcode_lines(handle, name or path.name, digest)
            except BadBgcode as error:
                raise BadGcode(str(error)) from None
            return
        handle.seek(start)
        offset = start
        # Read a line at most MAX_LINE_BYTES at a time: `for raw in handle` holds a
        # line of any length whole, and one line can be the whole upload.
        for raw in iter(partial(handle.readline, MAX_LINE_BYTES + 1), b""):
            if len(raw) > MAX_LINE_BYTES:
                raise BadGcode(_too_long(name or path.name, offset))
            offset += len(raw)
            if digest is not None:
                digest.update(raw)
            yield raw, offset


def _bgcode_lines(
    handle: BinaryIO, name: str, digest: Any
) -> Iterator[tuple[bytes, int]]:
    reader = BgcodeReader(handle, name=name, digest=digest)
    tail = b""  # a line a block cut (slicers never do; a hand-made file may)
    for block in reader.blocks():
        if block.type != BlockType.GCODE:
            continue
        if len(tail) > MAX_LINE_BYTES:  # else each block copies it again
            raise BadBgcode(_too_long(name, reader.offset))
        text = tail + block.data
        span, total, done = block.end - block.start, max(1, len(text)), 0
        # Lines end at b"\n" only, as a text file's do when read line by line.
        lines = text.split(b"\n")
        tail = lines.pop()
        for raw in lines:
            done += len(raw) + 1
            yield raw + b"\n", block.start + span * done // total
    if tail:
        yield tail, reader.offset


def _too_long(name: str, offset: int) -> str:
    return (
        f"{name}: a line near byte {offset} is longer than {MAX_LINE_BYTES >> 20} "
        "MB: not G-code"
    )


def inspect_file(
    path: Path, *, max_command_length: int = 0, name: str = "", grbl: bool = False
) -> FileFacts:
    """Check that *path* is a printable G-code file and measure it.

    Errors name the file *name* (the name the user gave it), else the path's name.

    1. Read it in chunks, hashing as we go (SHA-256); a binary G-code file is
       decoded block by block, each block's CRC32 checked.
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
    commands = longest = 0
    lines = file_lines(path, digest=digest, name=name)
    for number, (raw, _) in enumerate(lines, start=1):
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
    return FileFacts(path.stat().st_size, commands, digest.hexdigest(), longest)


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
