"""How each Marlin-like firmware words its line errors and orders its Resend and ok.

Wording facts (not code) from each firmware's sources:
- Marlin 2.1 (language.h): `Error:Line Number is not Last Line Number+1, Last
  Line: <n>`, `Error:checksum mismatch, Last Line: <n>`, `Error:No Checksum with
  line number, Last Line: <n>`; then `Resend: <n+1>` and `ok`.
- Prusa-Firmware (MK3, Marlin 1.x): the same, plus `Error:No Line Number with
  checksum, Last Line: <n>` for a `*` without `N`. It has no M410 (Marlin_main.cpp
  has no case for it): `echo:Unknown command: "M410"`, and the planner runs on.
- Repetier-Firmware (Communication.cpp, gcode.cpp): `Error:expected line <n+1>
  got <m>`, `Error:Wrong checksum`, `Error:Missing checksum`, `Error:Format
  error`; `Resend:<n+1>` and `ok`; a line it already had gets `skip <m>` and `ok`.
- Smoothieware (GcodeDispatch.cpp): `rs N<n+1>` alone, no Error line, no ok.
- RepRapFirmware 3 (StringParser.cpp): a bad or missing checksum drops the line
  with no reply at all; line numbers are not checked for sequence.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from printers.simulator import _marlin_text as text

__all__ = ["DIALECTS", "Dialect"]


@dataclass(frozen=True)
class Dialect:
    """One firmware's replies to a bad line; `last` is its last good line number."""

    name: str
    #: What it prints for each fault, {last} and {got} filled in; None: silence.
    line_number: str | None = f"Error:{text.ERR_LINE_NO}{{last}}"
    checksum: str | None = f"Error:{text.ERR_CHECKSUM}{{last}}"
    no_checksum: str | None = f"Error:{text.ERR_NO_CHECKSUM}{{last}}"
    #: A `*` on a line without `N`: an Error line alone, no Resend, no ok (Prusa,
    #: Marlin 1.x). None: the line runs unchecked, as in Marlin 2.
    no_line_number: str | None = None
    #: False: the no_line_number error comes alone (no Resend, no ok).
    resend_no_line_number: bool = True
    resend: str = "Resend: {next}"
    #: Where the ok of a rejected line goes: "after" the Resend, "before" it (a
    #: fault switch: some builds do), or "none" (no ok at all).
    ok_order: str = "after"
    #: Line numbers must follow each other (RepRapFirmware: not checked).
    sequence: bool = True
    #: A line numbered at or below the last good one gets `skip <m>` + ok.
    skip_duplicates: bool = False
    #: The ok of a numbered line names it (`ok <n>`, Repetier's ACK_WITH_LINENUMBER).
    numbered_ok: bool = False
    #: Commands this firmware does not have (answered `Unknown command`).
    lacks: frozenset[str] = frozenset()

    def supported(self, table: dict[str, Any]) -> dict[str, Any]:
        """A command table without the commands this firmware lacks."""
        return {name: run for name, run in table.items() if name not in self.lacks}

    def rejection(
        self, message: str | None, last: int, got: int | None, ok_order: str
    ) -> list[str]:
        """The lines printed for a rejected line (error, Resend and ok in order)."""
        if message is None:
            return []
        if message == self.no_line_number and not self.resend_no_line_number:
            return [message.format(last=last)]
        lines = [message.format(last=last, next=last + 1, got=got)] if message else []
        resend = self.resend.format(next=last + 1)
        if ok_order == "before":
            return [*lines, "ok", resend]
        if ok_order == "after":
            return [*lines, resend, "ok"]
        return [*lines, resend]


DIALECTS: dict[str, Dialect] = {
    # Like Prusa and Marlin 1.x, our Marlin refuses a `*` without `N` (the tail of
    # a line split by noise) instead of running it unchecked.
    "marlin": Dialect(
        "marlin",
        no_line_number="Error:No Line Number with checksum, Last Line: {last}",
        resend_no_line_number=False,
    ),
    "prusa": Dialect(
        "prusa",
        no_line_number="Error:No Line Number with checksum, Last Line: {last}",
        resend_no_line_number=False,
        lacks=frozenset({"M410"}),
    ),
    "repetier": Dialect(
        "repetier",
        line_number="Error:expected line {next} got {got}",
        checksum="Error:Wrong checksum",
        no_checksum="Error:Missing checksum",
        no_line_number="Error:Format error",
        resend="Resend:{next}",
        skip_duplicates=True,
        numbered_ok=True,
    ),
    "smoothieware": Dialect(
        "smoothieware",
        line_number="",
        checksum="",
        no_checksum="",
        resend="rs N{next}",
        ok_order="none",
    ),
    "reprapfirmware": Dialect(
        "reprapfirmware",
        line_number=None,
        checksum=None,
        no_checksum=None,
        sequence=False,
    ),
}
