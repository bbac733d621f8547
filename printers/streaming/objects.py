"""Objects of a file as its lines stream by, and skipping a cancelled one (sans-IO).

    objects = ObjectFilter(entries)       # Lines, plus ObjectMark for marker comments
    stream = Stream(..., lines=objects)   # the stream reads through the filter
    objects.cancel("box.stl")             # later lines of box.stl's extrusion go

Rules of this module:

O1. An object is named as the analysis names it (jobs/analysis/commands.py): the
    comment `; printing object NAME [id:N copy M]` (PrusaSlicer's label objects)
    up to `; stop printing object`, `EXCLUDE_OBJECT_START NAME=` up to
    `EXCLUDE_OBJECT_END` (Klipper), `M486 S<n>` after `M486 A<name>` up to
    `M486 S-1` (Marlin, RepRapFirmware). Names are stripped and cut at 200
    characters; copies of one object share its name (and its cancel).
O2. Comments never reach the firmware, so the reader hands marker comments in as
    `ObjectMark` entries (`object_mark` on the raw line); everything else is a Line.
O3. While a cancelled object's lines stream, a move that extrudes (E forward, with
    X, Y or an arc) is not sent. If it carries Z, a `G1 Z` with its Z is sent in
    its place (a layer change survives). In relative XYZ (G91) the move is sent
    without its E instead, so later relative moves still land where the file says.
O4. Everything else is sent as the file has it: travel moves, Z hops, retracts and
    unretracts (E-only moves, and wipes: moves that draw E back), temperatures,
    fans. So retracts and unretracts stay balanced and the slicer's travels and
    lifts are the ones that run.
    An E-forward move kept this way runs where the file has the head: if dropped
    moves left the head elsewhere, it travels there first (as in O7).
O5. E stays the file's: E the file extruded that was not sent is the lag. Before
    the next sent line that names E in absolute E (M82, G90), a `G92 E<the file's
    E>` is sent if there is a lag; relative E (M83, G91) needs nothing. G92 E in
    the file clears the lag (the line sets both).
O6. A dropped move's F still sets the feedrate: before the next sent move without
    its own F, `G1 F<the file's F>` is sent if the feedrate sent differs.
O7. When a cancelled object's part ends (its stop mark, another object's start),
    the head goes (`G0 X Y`, at the height it is at, inside the cancelled object's
    own area, which has nothing printed at this height) to where the file left
    it, so the slicer's own retract, lift and travel to the next object run from
    the point the slicer planned them from: no new path crosses another part.
O8. Lines added by the filter carry the index and file offset of the file's line
    before the one they precede (or of the line they replace), so acknowledging
    one never counts a line not yet sent as done; skipped lines are never
    yielded, and count as done once a later line is acknowledged (`Stream.done`).
O9. A cancel takes effect at the next line the filter reads: lines already read
    (sent, in flight, in the firmware's buffer) run as they are.
O10. A run resumed mid-file starts where the file's own lines left the filter
    (`place()`, kept with the resumed job): inside the object whose part was
    streaming, knowing the `M486 S` numbers named before the start line. Else the
    rest of a cancelled object's part, and every later part that `M486 S<n>`
    alone starts, would be printed again.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Any

from printers.streaming.object_marks import ObjectMark, object_mark, object_name
from printers.streaming.streams import Line

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator, Mapping

__all__ = ["ObjectFilter", "ObjectMark", "object_mark"]

_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")
#: A command's arguments as most lines write them (`_words`).
_PLAIN_WORDS = re.compile(r"[A-Z][-+]?[0-9.]+(?: [A-Z][-+]?[0-9.]+)*")
_E_WORD = re.compile(r"\s*[Ee]\s*[-+]?(?:\d+\.?\d*|\.\d+)")
_CODE = re.compile(r"^\s*([GMgm])\s*0*(\d+)(?![.\d])")
_NAME = re.compile(r"NAME=(\"[^\"]*\"|'[^']*'|\S+)", re.I)
_M486_NAME = re.compile(r"^\s*M486\s*A\s*(.+)$", re.I)
_M486_ID = re.compile(r"^\s*M486\s*S\s*(-?\d+)", re.I)
_XYZ = "XYZ"


def _number(value: float) -> str:
    """A coordinate as G-code writes it: no exponent, no trailing zeros."""
    text = f"{value:.5f}".rstrip("0").rstrip(".")
    return "0" if text in ("", "-0") else text


#: Plain moves followed at a time (`ObjectFilter._catch_up`).
FOLLOW_BATCH = 64


class ObjectFilter:
    """Reads a job's entries (Lines and ObjectMarks) and yields the Lines to send.

    Iterate it once (it is a stream's `lines`). `cancel(name)` may be called at any
    time between lines; `objects` lists the names seen so far, `m486_ids` the
    `M486 S` numbers of named objects (for firmware that cancels by itself).
    *place*: where a file read from its start stood before the entries begin
    (`place()`, O10), for a run resumed mid-file.
    """

    def __init__(
        self,
        entries: Iterable[Line | ObjectMark],
        *,
        cancelled: Iterable[str] = (),
        place: Mapping[str, Any] | None = None,
    ) -> None:
        self._entries = entries
        self.cancelled: set[str] = set(cancelled)
        #: Objects the firmware was told to cancel (M486 P): their lines go as is.
        self.firmware_cancelled: set[str] = set()
        self.objects: list[str] = []
        self.m486_ids: dict[str, int] = {}
        #: The object whose lines are streaming (None: none, or not named).
        self.active: str | None = None
        self._m486_names: dict[int, str] = {}
        self._m486_current = -1
        self._absolute = True
        self._absolute_e = True
        #: Where the file has put the head (absolute coordinates) and its E.
        self._file = {"X": 0.0, "Y": 0.0, "Z": 0.0}
        self._file_e = 0.0
        #: Where the head is: the file's position unless moves were dropped.
        self._head = dict(self._file)
        self._lag = 0.0
        #: The feedrate the file set last and the one the head got (None: none yet),
        #: as numbers: written out (`_number`) only when an F must be sent again.
        self._file_f: float | None = None
        self._head_f: float | None = None
        self._skipped_any = False
        self._prev = Line(-1, "", 0)
        #: Plain moves yielded whose positions are not followed yet (`_catch_up`).
        self._unfollowed: list[str] = []
        if place:
            self._take_place(place)

    def place(self) -> dict[str, Any]:
        """The object streaming and the names the file gave so far (O10), as JSON."""
        return {
            "active": self.active,
            "objects": list(self.objects),
            "m486": [[n, name] for n, name in self._m486_names.items()],
            "m486_current": self._m486_current,
        }

    def _take_place(self, place: Mapping[str, Any]) -> None:
        self.active = place.get("active")
        self.objects = list(place.get("objects") or ())
        for number, name in place.get("m486") or ():
            self._m486_names[int(number)] = name
            self.m486_ids.setdefault(name, int(number))
        self._m486_current = int(place.get("m486_current", -1))

    # -- control -----------------------------------------------------------------

    def cancel(self, name: str) -> None:
        """Skip *name*'s extrusion from the next line read on (rule O9)."""
        self.cancelled.add(name)

    @property
    def skipping(self) -> bool:
        return self.active is not None and self.active in self.cancelled

    # -- reading -----------------------------------------------------------------

    def __iter__(self) -> Iterator[Line]:
        unfollowed = self._unfollowed
        for entry in self._entries:
            if isinstance(entry, ObjectMark):
                self._catch_up()
                yield from self._enter(entry.name)
                continue
            head = entry.text[:3]
            if (head == "G1 " or head == "G0 ") and self._plain():
                # Followed later, in a batch (a plain move changes nothing
                # `_plain` asks): one line goes a turn, and code run once a turn
                # runs with the processor's caches cold.
                unfollowed.append(entry.text)
                if len(unfollowed) >= FOLLOW_BATCH:
                    self._catch_up()
                yield entry
            else:
                self._catch_up()
                yield from self._line(entry)
            self._prev = entry

    def _catch_up(self) -> None:
        """Follow the plain moves yielded since the last catch-up, in order: before
        anything that reads the positions, E or the feedrate."""
        if self._unfollowed:
            for text in self._unfollowed:
                self._follow(text[3:])
            self._unfollowed.clear()

    def _plain(self) -> bool:
        """Nothing skipped and nothing owed (no E lag, the feedrate sent): a move
        goes as the file has it and only moves the positions (`_follow`)."""
        return (
            not self._lag
            and self._head_f == self._file_f
            and (self.active is None or self.active not in self.cancelled)
        )

    def _follow(self, args: str) -> None:
        """`_move` for a plain move (see `_plain`), without what only skipping needs:
        most lines of a file come here."""
        given = _words(args)
        if "E" in given:
            value = given["E"]
            self._file_e += value - self._file_e if self._absolute_e else value
        if "F" in given:
            self._file_f = self._head_f = given["F"]
        file, head = self._file, self._head
        for axis in _XYZ:
            if axis in given:
                value = given[axis]
                file[axis] = head[axis] = (
                    value if self._absolute else file[axis] + value
                )

    def _enter(self, name: str | None) -> Iterator[Line]:
        """An object starts (or, None, stops): leave a skipped part where the file is."""
        if self.skipping and name != self.active:
            yield from self._return_head()
        self.active = name
        if name is not None and name not in self.objects:
            self.objects.append(name)

    def _line(self, line: Line) -> Iterator[Line]:
        text = line.text
        code = _CODE.match(text)
        if code is None:
            label = _klipper_label(text)
            if label is not None:
                yield from self._enter(label or None)
            yield line
            return
        letter, number = code.group(1).upper(), int(code.group(2))
        if letter == "G" and number <= 3:
            yield from self._move(line, text[code.end() :])
            return
        if letter == "M" and number == 486:
            yield from self._m486(text)
        elif letter == "G":
            self._g_code(number, text[code.end() :])
        elif letter == "M" and number in (82, 83):
            self._absolute_e = number == 82
        yield line

    def _m486(self, text: str) -> Iterator[Line]:
        named = _M486_NAME.match(text)
        if named is not None:
            name = object_name(named.group(1))
            if self._m486_current >= 0:
                self._m486_names[self._m486_current] = name
                self.m486_ids.setdefault(name, self._m486_current)
            yield from self._enter(name)
            return
        number = _M486_ID.match(text)
        if number is not None:
            self._m486_current = int(number.group(1))
            yield from self._enter(self._m486_names.get(self._m486_current))

    def _g_code(self, number: int, args: str) -> None:
        if number == 90:
            self._absolute = self._absolute_e = True
        elif number == 91:
            self._absolute = self._absolute_e = False
        elif number == 92:
            given = _words(args)
            if not given:
                given = {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}
            for axis in _XYZ:
                if axis in given:
                    self._file[axis] = self._head[axis] = given[axis]
            if "E" in given:
                self._file_e, self._lag = given["E"], 0.0
        elif number == 28:
            # Homed axes are where the firmware says; the file and the head agree.
            self._head = dict(self._file)

    # -- moves -------------------------------------------------------------------

    def _move(self, line: Line, args: str) -> Iterator[Line]:
        given = _words(args)
        file_before = self._file_e
        forward = 0.0
        if "E" in given:
            forward = given["E"] - self._file_e if self._absolute_e else given["E"]
            self._file_e += forward
        if "F" in given:
            self._file_f = given["F"]
        target = {}
        for axis in _XYZ:
            if axis in given:
                value = given[axis]
                target[axis] = value if self._absolute else self._file[axis] + value
        moves = any(target.get(a, self._file[a]) != self._file[a] for a in "XY")
        self._file.update(target)
        draws = forward > 0 and (moves or any(k in given for k in "IJR"))
        if draws and self.skipping:
            yield from self._drop(line, given, forward)
            return
        if forward > 0 and self.skipping:
            # An unretract or a prime in place (O4) extrudes where the file has the
            # head: after dropped moves the head is elsewhere, and the E would draw
            # a line from there. It goes to the file's place first (O7's travel).
            yield from self._return_head()
        if "E" in given and self._absolute_e and self._lag:
            yield self._added(f"G92 E{_number(file_before)}")
            self._lag = 0.0
        if (
            "F" not in given
            and self._head_f != self._file_f
            and self._file_f is not None
        ):
            yield self._added(f"G1 F{_number(self._file_f)}")
        self._head.update(target)
        if "F" in given:
            self._head_f = self._file_f
        yield line

    def _drop(
        self, line: Line, given: dict[str, float], forward: float
    ) -> Iterator[Line]:
        """Rule O3: an extruding move of a cancelled object."""
        self._lag += forward
        self._skipped_any = True
        if not self._absolute:
            text = _E_WORD.sub("", line.text, count=1)
            # Everything but E moves as the file says (relative moves add up).
            self._head.update(self._file)
            if "F" in given:
                self._head_f = self._file_f
            yield Line(line.index, text, line.end_offset)
            return
        if "Z" in given and self._head["Z"] != self._file["Z"]:
            self._head["Z"] = self._file["Z"]
            yield Line(line.index, f"G1 Z{_number(self._file['Z'])}", line.end_offset)

    def _return_head(self) -> Iterator[Line]:
        """Rule O7: to where the file left the head, inside the cancelled object."""
        if not self._absolute:
            return
        moved = [a for a in ("X", "Y") if self._head[a] != self._file[a]]
        if moved:
            words = " ".join(f"{a}{_number(self._file[a])}" for a in ("X", "Y"))
            yield self._added(f"G0 {words}")
            self._head.update({a: self._file[a] for a in ("X", "Y")})

    def _added(self, text: str) -> Line:
        """A line the filter adds before the next one read (rule O8)."""
        return Line(self._prev.index, text, self._prev.end_offset)


def _klipper_label(text: str) -> str | None:
    """EXCLUDE_OBJECT_START NAME=x -> "x", EXCLUDE_OBJECT_END -> "", else None."""
    head = text.lstrip()[:20].upper()
    if head == "EXCLUDE_OBJECT_START":
        found = _NAME.search(text)
        return object_name(found.group(1)) if found is not None else None
    if head.startswith("EXCLUDE_OBJECT_END"):
        return ""
    return None


def _words(args: str) -> dict[str, float]:
    """The words of a command's arguments, by upper-case letter.

    Most lines are words of an upper-case letter and a plain number, one space
    apart (`X12.5 Y3 E.04`): checked so by one match (_PLAIN_WORDS), then split;
    anything else (`X 12`, `X1Y2`, `x1`, an exponent, which G-code has not) goes
    through _WORD.
    """
    if _PLAIN_WORDS.fullmatch(args):
        try:  # "X1.2.3" passes the pattern, not float(): _WORD reads it
            return {word[0]: float(word[1:]) for word in args.split(" ")}
        except ValueError:
            pass
    return {letter.upper(): float(value) for letter, value in _WORD.findall(args)}
