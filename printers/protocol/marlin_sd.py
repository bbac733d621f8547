"""The printer's own SD card, as Marlin talks about it: what to send, what it answers.

Sans-IO like the rest of the protocol: `SdDialogue.receive(text)` takes one response
line (already stripped of its line end) and returns an `SdEvent`, or None when the
line is not about the SD card. A file list spans many lines (`Begin file list` ...
`End file list`); the dialogue gathers them and returns one `SdListed`.

The words are Marlin's (`Marlin/src/core/language.h`, `sd/cardreader.cpp`):

    M20 [L]          Begin file list / NAME.GCO 1234 [Long name.gcode] / End file list
    M21              echo:SD card ok | echo:SD init fail | echo:No SD card / No media
    M23 NAME.GCO     echo:Now fresh file: NAME.GCO / File opened: NAME.GCO Size: 1234
                     / File selected   | echo:open failed, File: NAME.GCO.
    M24 / M25        start or resume / pause the selected file
    M27 [S<s>]       SD printing byte 120/1234 | Not SD printing  (S: every s seconds)
    M28 NAME.GCO     Writing to file: NAME.GCO   (numbered lines go to the file, acked)
    M29              Done saving file.
    M30 NAME.GCO     File deleted:NAME.GCO | Deletion failed, File: NAME.GCO.
    M524             abort the SD print
    end of file      Done printing file

Names on the card are 8.3 upper case (`short_name`); `M20 L` adds the long name.
"""

from __future__ import annotations

import re
import unicodedata
from dataclasses import dataclass

__all__ = [
    "SdCardState",
    "SdDeleteFailed",
    "SdDeleted",
    "SdDialogue",
    "SdDone",
    "SdEvent",
    "SdFile",
    "SdFileOpened",
    "SdListed",
    "SdNotPrinting",
    "SdOpenFailed",
    "SdProgress",
    "SdSaved",
    "SdWriting",
    "short_name",
]


@dataclass(frozen=True, slots=True)
class SdFile:
    """One file on the card: its 8.3 name (the one M23 takes), size, long name."""

    name: str
    size: int
    long_name: str = ""


@dataclass(frozen=True, slots=True)
class SdListed:
    """The whole answer to M20."""

    files: tuple[SdFile, ...]


@dataclass(frozen=True, slots=True)
class SdCardState:
    """M21's answer, or a card inserted or removed."""

    present: bool
    message: str


@dataclass(frozen=True, slots=True)
class SdFileOpened:
    """M23 opened *name* for printing; *size* bytes."""

    name: str
    size: int


@dataclass(frozen=True, slots=True)
class SdOpenFailed:
    name: str


@dataclass(frozen=True, slots=True)
class SdProgress:
    """`SD printing byte <position>/<total>` (M27, or its auto-report)."""

    position: int
    total: int

    @property
    def share(self) -> float:
        return 0.0 if self.total <= 0 else min(1.0, self.position / self.total)


@dataclass(frozen=True, slots=True)
class SdNotPrinting:
    """M27 while no file is printing (never started, paused by M25 not included)."""


@dataclass(frozen=True, slots=True)
class SdDone:
    """`Done printing file`: the firmware read the whole file."""


@dataclass(frozen=True, slots=True)
class SdWriting:
    """M28 opened *name*: numbered lines now go to the file, not to the planner."""

    name: str


@dataclass(frozen=True, slots=True)
class SdSaved:
    """M29: the file is closed and saved."""


@dataclass(frozen=True, slots=True)
class SdDeleted:
    name: str


@dataclass(frozen=True, slots=True)
class SdDeleteFailed:
    name: str


SdEvent = (
    SdListed
    | SdCardState
    | SdFileOpened
    | SdOpenFailed
    | SdProgress
    | SdNotPrinting
    | SdDone
    | SdWriting
    | SdSaved
    | SdDeleted
    | SdDeleteFailed
)

_PROGRESS = re.compile(r"^SD printing byte (\d+)\s*/\s*(\d+)")
_OPENED = re.compile(r"^File opened:\s*(\S+)\s+Size:\s*(\d+)")
_LIST_ENTRY = re.compile(r"^(\S+)\s+(\d+)(?:\s+(.*))?$")
_CARD = {
    "SD card ok": True,
    "SD init fail": False,
    "No SD card": False,
    "No media": False,
    "SD card released": False,
    "SD card inserted": True,
    "SD card removed": False,
}


#: Lines that start like this are never about the card (a fast exit for oks).
_NOT_ABOUT_THE_CARD = ("ok", " T:", "T:", "busy:", "echo:busy:", "Resend:", "wait")
_SIMPLE: dict[str, SdEvent] = {
    "Not SD printing": SdNotPrinting(),
    "Done printing file": SdDone(),
    "Done saving file.": SdSaved(),
}


class SdDialogue:
    """Turns response lines about the SD card into events; gathers M20's list."""

    def __init__(self) -> None:
        self._listing: list[SdFile] | None = None

    @property
    def listing(self) -> bool:
        """True between `Begin file list` and `End file list`."""
        return self._listing is not None

    def receive(self, text: str) -> SdEvent | None:
        """One response line; an event when it is about the SD card, else None.

        Called for every line the printer sends: an `ok` (most of them, while a job
        streams) or a temperature report costs one prefix test.
        """
        if self._listing is None and text.startswith(_NOT_ABOUT_THE_CARD):
            return None
        line = text.strip()
        if line.startswith("echo:"):
            line = line[5:].strip()
        if self._listing is not None:
            return self._list_line(line)
        if line == "Begin file list":
            self._listing = []
            return None
        return _parse(line)

    def _list_line(self, line: str) -> SdEvent | None:
        assert self._listing is not None
        # M20's ok ends the list too, when line noise took `End file list` away.
        if line == "End file list" or line == "ok" or line.startswith("ok "):
            files, self._listing = tuple(self._listing), None
            return SdListed(files)
        match = _LIST_ENTRY.match(line)
        if match is not None:
            name, size, long_name = match.groups()
            self._listing.append(SdFile(name, int(size), (long_name or "").strip()))
        return None


def _parse(line: str) -> SdEvent | None:
    if match := _PROGRESS.match(line):
        return SdProgress(int(match[1]), int(match[2]))
    if match := _OPENED.match(line):
        return SdFileOpened(match[1], int(match[2]))
    if line in _SIMPLE:
        return _SIMPLE[line]
    if line in _CARD:
        return SdCardState(_CARD[line], line)
    for prefix, kind in (
        ("Writing to file:", SdWriting),
        ("open failed, File:", SdOpenFailed),
        ("File deleted:", SdDeleted),
        ("Deletion failed, File:", SdDeleteFailed),
    ):
        if line.startswith(prefix):
            return kind(line[len(prefix) :].strip().rstrip("."))
    return None


#: Brackets are left out too: a name the host makes must be one it can send.
_NOT_IN_SHORT_NAMES = re.compile(r"[^A-Z0-9_~!#$%&'@^`{}-]")


def short_name(name: str, taken: set[str] | frozenset[str] = frozenset()) -> str:
    """An 8.3 upper-case name for *name* that is not in *taken* (upper case).

    `part holder v2.gcode` -> `PARTHO~1.GCO`; names that already fit stay as they are
    (upper-cased). Marlin's SD library writes 8.3 names only, so the host picks the
    name it will later print by.
    """
    name = unicodedata.normalize("NFKD", name)
    stem, dot, extension = name.rpartition(".")
    if not dot:
        stem, extension = name, ""
    stem = _NOT_IN_SHORT_NAMES.sub("", stem.upper()) or "FILE"
    extension = _NOT_IN_SHORT_NAMES.sub("", extension.upper())[:3]
    suffix = f".{extension}" if extension else ""
    if len(stem) <= 8 and f"{stem}{suffix}" not in taken:
        return f"{stem}{suffix}"
    for number in range(1, 1000):
        tail = f"~{number}"
        candidate = f"{stem[: 8 - len(tail)]}{tail}{suffix}"
        if candidate not in taken:
            return candidate
    raise ValueError(f"no free 8.3 name for {name!r}")
