"""The simulated Marlin's SD card: files by 8.3 name, one open for printing or writing.

The firmware hands it the SD commands (`handlers()`), asks `capture()` about every
checked line while M28 is writing (those lines go to the file and are acked, never
run), pulls the printing file's next command with `next_command()` when a queue slot
is free, and calls `tick()` for the M27 S<n> auto-report. It answers in Marlin's
words (see `printers/protocol/marlin_sd.py`).
"""

from __future__ import annotations

import re
from collections.abc import Iterator, MutableMapping
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    Handler = Callable[[str, float], None]

__all__ = ["CardFiles", "SdCard"]

#: What Marlin takes for M29 while it writes a file (queue.cpp's is_M29).
_M29 = re.compile(r"M29(?![0-9])")

#: Names a directory-backed card lists: 8.3, upper case (what Marlin's M28 writes).
_SHORT = re.compile(
    r"^[A-Z0-9_~!#$%&'()@^`{}-]{1,8}(\.[A-Z0-9_~!#$%&'()@^`{}-]{1,3})?$"
)


class CardFiles(MutableMapping[str, bytes]):
    """The card's files by 8.3 name: in memory, or the files of a directory (so a
    test can put a file on the card before the printer starts and read what an
    upload wrote)."""

    def __init__(self, directory: Path | None = None) -> None:
        self.directory = directory
        self._memory: dict[str, bytes] = {}

    def __getitem__(self, name: str) -> bytes:
        if self.directory is None:
            return self._memory[name]
        path = self.directory / name
        if not _SHORT.match(name) or not path.is_file():
            raise KeyError(name)
        return path.read_bytes()

    def __setitem__(self, name: str, data: bytes) -> None:
        if self.directory is None:
            self._memory[name] = data
        else:
            (self.directory / name).write_bytes(data)

    def __delitem__(self, name: str) -> None:
        if self.directory is None:
            del self._memory[name]
            return
        if name not in self:
            raise KeyError(name)
        (self.directory / name).unlink()

    def __iter__(self) -> Iterator[str]:
        if self.directory is None:
            return iter(sorted(self._memory))
        names = (p.name for p in self.directory.iterdir() if p.is_file())
        return iter(sorted(n for n in names if _SHORT.match(n)))

    def __len__(self) -> int:
        return sum(1 for _ in self)

    def append(self, name: str, data: bytes) -> None:
        """Add *data* at the end of *name* (M28 writing, line by line)."""
        if self.directory is None:
            self._memory[name] = self._memory.get(name, b"") + data
        else:
            with (self.directory / name).open("ab") as out:
                out.write(data)

    def size(self, name: str) -> int:
        if self.directory is None:
            return len(self._memory[name])
        return (self.directory / name).stat().st_size


class SdCard:
    """Files on the card, the selected file and where reading has got to."""

    def __init__(self, say: Callable[..., None], directory: Path | None = None) -> None:
        self.say = say
        self.files = CardFiles(directory)
        self.selected: str | None = None
        self.position = 0
        self.printing = False
        self.writing: str | None = None
        self.report_every = 0.0
        self._next_report = 0.0
        #: The selected file as it was opened (M23 reads it once, like a file handle).
        self._data = b""

    def handlers(self) -> dict[str, Handler]:
        return {
            "M20": self._m20,
            "M21": self._m21,
            "M23": self._m23,
            "M24": self._m24,
            "M25": self._m25,
            "M26": self._m26,
            "M27": self._m27,
            "M28": self._m28,
            "M29": self._m29,
            "M30": self._m30,
            "M524": self._m524,
        }

    def reset(self) -> None:
        """A reboot closes every file; what was saved stays on the card."""
        self.selected, self.position, self.printing, self.writing = None, 0, False, None
        self.report_every = 0.0

    # -- M28 writing -------------------------------------------------------------

    def capture(self, text: str) -> bool:
        """While writing, *text* (a checked command) goes to the file; True if taken.

        M29 ends the writing and is taken too (answered "Done saving file."). As
        Marlin's is_M29 does, "M29" anywhere in the line not followed by a digit
        ends it: `M117 Copy M29 ok` closes the file, and the lines after it run.
        """
        if self.writing is None:
            return False
        if _M29.search(text):
            self._m29("", 0.0)
            return True
        self.files.append(self.writing, text.encode("ascii", "replace") + b"\n")
        return True

    # -- printing ----------------------------------------------------------------

    def next_command(self) -> str | None:
        """The printing file's next command (comments and blanks skipped), or None.

        At the end of the file: "Done printing file", and printing stops.
        """
        if not self.printing or self.selected is None:
            return None
        data = self._data
        while self.position < len(data):
            end = data.find(b"\n", self.position)
            end = len(data) if end < 0 else end + 1
            raw = data[self.position : end]
            self.position = end
            text = raw.split(b";", 1)[0].decode("ascii", "replace").strip()
            if text:
                return text
        self.printing = False
        self.say("Done printing file")
        return None

    def next_report(self) -> float | None:
        """When `tick` reports next (M27 S<n>), or None."""
        return self._next_report if self.report_every > 0 else None

    def tick(self, now: float) -> None:
        """The M27 S<n> auto-report (Marlin reports whether a file prints or not)."""
        if self.report_every <= 0 or now < self._next_report:
            return
        self._next_report = now + self.report_every
        self._report()

    # -- the commands ------------------------------------------------------------

    def _m20(self, args: str, now: float) -> None:
        long_names = "L" in args.upper().split()
        self.say("Begin file list")
        for name in sorted(self.files):
            extra = f" {name.lower()}" if long_names else ""
            self.say(f"{name} {self.files.size(name)}{extra}")
        self.say("End file list")

    def _m21(self, args: str, now: float) -> None:
        self.say("echo:SD card ok")

    def _m23(self, args: str, now: float) -> None:
        name = args.strip().upper()
        if name not in self.files:
            self.say(f"echo:open failed, File: {name}.")
            return
        self.selected, self.position, self.printing = name, 0, False
        self._data = self.files[name]
        self.say(f"echo:Now fresh file: {name}")
        self.say(f"File opened: {name} Size: {self.files.size(name)}")
        self.say("File selected")

    def _m24(self, args: str, now: float) -> None:
        if self.selected is not None:
            self.printing = True

    def _m25(self, args: str, now: float) -> None:
        self.printing = False

    def _m26(self, args: str, now: float) -> None:
        for word in args.split():
            if word[:1].upper() == "S" and word[1:].isdigit():
                self.position = int(word[1:])

    def _m27(self, args: str, now: float) -> None:
        for word in args.split():
            if word[:1].upper() == "S":
                self.report_every = float(word[1:] or 0)
                self._next_report = now + self.report_every
                return
        self._report()

    def _m28(self, args: str, now: float) -> None:
        name = args.strip().upper()
        self.files[name] = b""
        self.writing = name
        self.say(f"Writing to file: {name}")

    def _m29(self, args: str, now: float) -> None:
        if self.writing is not None:
            self.writing = None
            self.say("Done saving file.")

    def _m30(self, args: str, now: float) -> None:
        name = args.strip().upper()
        if self.files.pop(name, None) is None:
            self.say(f"Deletion failed, File: {name}.")
            return
        if self.selected == name:
            self.reset()
        self.say(f"File deleted:{name}")

    def _m524(self, args: str, now: float) -> None:
        self.printing, self.selected, self.position = False, None, 0
        self._data = b""

    def stop_from_display(self) -> bool:
        """The printer's own menu stops the print (the host is not told); False if
        nothing was printing."""
        if self.selected is None:
            return False
        self._m524("", 0.0)
        return True

    def _report(self) -> None:
        if self.printing and self.selected is not None:
            size = len(self._data)
            self.say(f"SD printing byte {self.position}/{size}")
        else:
            self.say("Not SD printing")
