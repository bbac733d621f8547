"""The simulated Marlin's SD card: files by 8.3 name, one open for printing or writing.

The firmware hands it the SD commands (`handlers()`), asks `capture()` about every
checked line while M28 is writing (those lines go to the file and are acked, never
run), pulls the printing file's next command with `next_command()` when a queue slot
is free, and calls `tick()` for the M27 S<n> auto-report. It answers in Marlin's
words (see `printers/protocol/marlin_sd.py`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Callable

    Handler = Callable[[str, float], None]

__all__ = ["SdCard"]


class SdCard:
    """Files on the card, the selected file and where reading has got to."""

    def __init__(self, say: Callable[..., None]) -> None:
        self.say = say
        self.files: dict[str, bytes] = {}
        self.selected: str | None = None
        self.position = 0
        self.printing = False
        self.writing: str | None = None
        self.report_every = 0.0
        self._next_report = 0.0

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

        M29 ends the writing and is taken too (answered "Done saving file.").
        """
        if self.writing is None:
            return False
        if text.split(maxsplit=1)[:1] == ["M29"]:
            self._m29("", 0.0)
            return True
        self.files[self.writing] += text.encode("ascii", "replace") + b"\n"
        return True

    # -- printing ----------------------------------------------------------------

    def next_command(self) -> str | None:
        """The printing file's next command (comments and blanks skipped), or None.

        At the end of the file: "Done printing file", and printing stops.
        """
        if not self.printing or self.selected is None:
            return None
        data = self.files.get(self.selected, b"")
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

    def tick(self, now: float) -> None:
        """The M27 S<n> auto-report, while a file is selected."""
        if self.report_every <= 0 or self.selected is None or now < self._next_report:
            return
        self._next_report = now + self.report_every
        self._report()

    # -- the commands ------------------------------------------------------------

    def _m20(self, args: str, now: float) -> None:
        long_names = "L" in args.upper().split()
        self.say("Begin file list")
        for name in sorted(self.files):
            extra = f" {name.lower()}" if long_names else ""
            self.say(f"{name} {len(self.files[name])}{extra}")
        self.say("End file list")

    def _m21(self, args: str, now: float) -> None:
        self.say("echo:SD card ok")

    def _m23(self, args: str, now: float) -> None:
        name = args.strip().upper()
        if name not in self.files:
            self.say(f"echo:open failed, File: {name}.")
            return
        self.selected, self.position, self.printing = name, 0, False
        self.say(f"echo:Now fresh file: {name}")
        self.say(f"File opened: {name} Size: {len(self.files[name])}")
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

    def _report(self) -> None:
        if self.printing and self.selected is not None:
            size = len(self.files[self.selected])
            self.say(f"SD printing byte {self.position}/{size}")
        else:
            self.say("Not SD printing")
