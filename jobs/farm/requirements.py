"""What a farm job asks of a printer, and whether a printer meets it (pure: no Django).

A farm job may ask for a loaded material and colour, a nozzle diameter, a printer
profile and tags; its analysed bounding box must fit in the printer's build volume,
and its longest command must fit the printer's firmware. Each is optional except
the last two, which come from the file. The checks run in a fixed order
(`CHECKS`), so when no printer meets them all, the reason names the first
requirement that left none, in words a person acts on ("no printer has PETG
loaded"), with the ones met so far ("no printer with PETG loaded has a 0.6 mm
nozzle").

Text compares without case or surrounding blanks; nozzles within 0.001 mm; a part
fits a volume with 0.01 mm to spare (slicers place skirts on the bed's edge).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Mapping, Sequence

#: (min x, y, z), (max x, y, z) in mm.
Box = tuple[tuple[float, float, float], tuple[float, float, float]]

#: Longest material, colour or profile name, and tag (the printer's own fields).
MAX_TEXT = {"material": 32, "colour": 32, "profile": 100}
MAX_TAG = 40
MAX_TAGS = 20
NOZZLE_TOLERANCE = 0.001
FIT_TOLERANCE = 0.01
#: Between a part's sizes (the multiplication sign).
TIMES = "\u00d7"


class BadRequirement(ValueError):
    """A requirement that cannot be met by any printer as written (HTTP 400)."""


def _norm(text: str) -> str:
    return " ".join(text.split()).casefold()


@dataclass(frozen=True, slots=True)
class Requirements:
    """What one farm job asks for; empty fields ask for nothing."""

    material: str = ""
    colour: str = ""
    nozzle: float | None = None
    profile: str = ""
    tags: tuple[str, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        return {
            "material": self.material,
            "colour": self.colour,
            "nozzle_diameter": self.nozzle,
            "profile": self.profile,
            "tags": list(self.tags),
        }

    def describe(self) -> str:
        """`red PETG, 0.6 mm nozzle, profile MK4, tags enclosed` ("any printer")."""
        parts = [
            _loaded_words(self),
            f"{self.nozzle:g} mm nozzle" if self.nozzle is not None else "",
            f"profile {self.profile}" if self.profile else "",
            f"{_plural('tag', self.tags)} {', '.join(self.tags)}" if self.tags else "",
        ]
        return ", ".join(p for p in parts if p) or "any printer"


@dataclass(frozen=True, slots=True)
class PrinterFacts:
    """What the matcher knows of one printer (read from its row)."""

    slug: str
    material: str = ""
    colour: str = ""
    nozzle: float | None = None
    profile: str = ""
    tags: tuple[str, ...] = ()
    volume: Box | None = None
    command_limit: int = 0  # 0 = no limit known
    extra: dict[str, Any] = field(default_factory=dict, compare=False)


def _plural(word: str, items: Sequence[object]) -> str:
    return word if len(items) == 1 else f"{word}s"


def _loaded_words(req: Requirements) -> str:
    return " ".join(w for w in (req.colour, req.material) if w)


def _text(values: Mapping[str, Any], *names: str) -> str:
    for name in names:
        value = values.get(name)
        if isinstance(value, list | tuple):
            value = value[-1] if value else ""
        if value not in (None, ""):
            if not isinstance(value, str):
                raise BadRequirement(f"{names[0]} must be text, not {value!r}")
            return " ".join(value.split())
    return ""


def parse_requirements(values: Mapping[str, Any]) -> Requirements:
    """Requirements from form fields, query parameters or a JSON object.

    Names: `material`, `colour` (or `color`), `nozzle` (or `nozzle_diameter`, mm),
    `profile`, `tags` (a list, or words separated by commas). BadRequirement says
    which one is wrong and how.
    """
    found: dict[str, str] = {}
    for name, aliases in (
        ("material", ("material",)),
        ("colour", ("colour", "color")),
        ("profile", ("profile",)),
    ):
        text = _text(values, *aliases)
        if len(text) > MAX_TEXT[name]:
            raise BadRequirement(
                f"{name} is at most {MAX_TEXT[name]} characters, not {len(text)}"
            )
        if any(not c.isprintable() for c in text):
            raise BadRequirement(f"{name} may hold printable characters only")
        found[name] = text
    return Requirements(
        material=found["material"],
        colour=found["colour"],
        nozzle=parse_nozzle(values.get("nozzle", values.get("nozzle_diameter"))),
        profile=found["profile"],
        tags=parse_tags(values.get("tags")),
    )


def parse_nozzle(value: object) -> float | None:
    """A nozzle diameter in mm (0.05 to 5), or None when not given."""
    if isinstance(value, list | tuple):
        value = value[-1] if value else None
    if value in (None, ""):
        return None
    if isinstance(value, bool):
        raise BadRequirement(f"nozzle must be a diameter in mm, not {value!r}")
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError, OverflowError):  # OverflowError: a huge integer
        raise BadRequirement(
            f"nozzle must be a diameter in mm (e.g. 0.4), not {str(value)[:40]!r}"
        ) from None
    if not math.isfinite(number) or not 0.05 <= number <= 5:
        raise BadRequirement(f"nozzle must be between 0.05 and 5 mm, not {value!r}")
    return round(number, 3)


def parse_tags(value: object) -> tuple[str, ...]:
    """Tags from a list or comma-separated words: unique, in the order given."""
    if value in (None, ""):
        return ()
    items: Iterable[object]
    if isinstance(value, str):
        items = value.split(",")
    elif isinstance(value, list | tuple):
        if not all(isinstance(item, str) for item in value):
            raise BadRequirement(f"tags must be words, not {value!r}")
        items = [part for item in value for part in item.split(",")]
    else:
        raise BadRequirement(f"tags must be a list or comma-separated words: {value!r}")
    tags: list[str] = []
    seen: set[str] = set()
    for item in items:
        tag = " ".join(item.split())
        if not tag:
            continue
        if len(tag) > MAX_TAG or any(not c.isprintable() for c in tag):
            raise BadRequirement(f"a tag is 1 to {MAX_TAG} printable characters")
        if _norm(tag) not in seen:
            seen.add(_norm(tag))
            tags.append(tag)
            if len(tags) > MAX_TAGS:
                raise BadRequirement(f"at most {MAX_TAGS} tags")
    return tuple(tags)


def box_of(value: object) -> Box | None:
    """A box from a build volume ({"min", "max"}) or an analysis' bbox ([min, max]);
    None when unknown or malformed."""
    corners: object = value
    if isinstance(value, dict):
        corners = [value.get("min"), value.get("max")]
    if not isinstance(corners, list | tuple) or len(corners) != 2:
        return None
    try:
        low, high = (tuple(float(v) for v in corner) for corner in corners)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        return None
    if len(low) != 3 or len(high) != 3:
        return None
    return (low[0], low[1], low[2]), (high[0], high[1], high[2])


def fits(part: Box, volume: Box, *, tolerance: float = FIT_TOLERANCE) -> bool:
    """Every corner of *part* lies inside *volume* (both in machine coordinates)."""
    (plo, phi), (vlo, vhi) = part, volume
    return all(
        plo[axis] >= vlo[axis] - tolerance and phi[axis] <= vhi[axis] + tolerance
        for axis in range(3)
    )


def size_text(box: Box) -> str:
    """The box's extent along x, y and z: `250×210×180 mm` (the sign is U+00D7)."""  # noqa: RUF002
    low, high = box
    sizes = (round(high[axis] - low[axis], 1) for axis in range(3))
    return TIMES.join(f"{size:g}" for size in sizes) + " mm"


def volume_size(box: Box | None) -> float:
    """The box's volume in mm³ (infinite when unknown: sorts last)."""
    if box is None:
        return math.inf
    low, high = box
    return math.prod(high[axis] - low[axis] for axis in range(3))


# -- the checks, in the order a reason is given -------------------------------------


@dataclass(frozen=True, slots=True)
class Part:
    """What the file itself asks: its analysed box (None: no extent) and longest
    command."""

    box: Box | None = None
    longest: int = 0


def _same(asked: str, held: str) -> bool:
    return not asked or _norm(asked) == _norm(held)


def _tags_held(req: Requirements, printer: PrinterFacts) -> bool:
    held = {_norm(tag) for tag in printer.tags}
    return all(_norm(tag) in held for tag in req.tags)


def _nozzle_held(req: Requirements, printer: PrinterFacts) -> bool:
    if req.nozzle is None:
        return True
    return (
        printer.nozzle is not None
        and abs(printer.nozzle - req.nozzle) <= NOZZLE_TOLERANCE
    )


def _fits(part: Part, printer: PrinterFacts) -> bool:
    if part.box is None:
        return True
    return printer.volume is not None and fits(part.box, printer.volume)


def _command_fits(part: Part, printer: PrinterFacts) -> bool:
    return not printer.command_limit or part.longest <= printer.command_limit


Check = tuple[str, "Callable[[Requirements, Part, PrinterFacts], bool]"]

#: Each requirement, in the order reasons name them.
CHECKS: tuple[Check, ...] = (
    ("material", lambda r, p, f: _same(r.material, f.material)),
    ("colour", lambda r, p, f: _same(r.colour, f.colour)),
    ("nozzle", lambda r, p, f: _nozzle_held(r, f)),
    ("profile", lambda r, p, f: _same(r.profile, f.profile)),
    ("tags", lambda r, p, f: _tags_held(r, f)),
    ("volume", lambda r, p, f: _fits(p, f)),
    ("command", lambda r, p, f: _command_fits(p, f)),
)


def unmet(req: Requirements, part: Part, printer: PrinterFacts) -> str | None:
    """The first requirement *printer* does not meet (a `CHECKS` name), or None."""
    for name, check in CHECKS:
        if not check(req, part, printer):
            return name
    return None


def matching(
    req: Requirements, part: Part, printers: Iterable[PrinterFacts]
) -> list[PrinterFacts]:
    """The printers that meet every requirement, in the order given."""
    return [p for p in printers if unmet(req, part, p) is None]


def why_none_match(
    req: Requirements, part: Part, printers: Sequence[PrinterFacts]
) -> str:
    """Why no printer of *printers* meets the job's requirements ("" if one does)."""
    if not printers:
        return "no printer takes farm jobs (turn on “farm” on a printer)"
    left = list(printers)
    for name, check in CHECKS:
        kept = [p for p in left if check(req, part, p)]
        if not kept:
            return _reason(name, req, part, left)
        left = kept
    return ""


def _met_so_far(name: str, req: Requirements) -> str:
    """` with red PETG loaded and a 0.6 mm nozzle`: the requirements checked before
    *name* that the printers left still meet."""
    order = [check for check, _ in CHECKS]
    before = set(order[: order.index(name)])
    parts = []
    loaded = " ".join(
        w
        for key, w in (("colour", req.colour), ("material", req.material))
        if key in before and w
    )
    if loaded:
        parts.append(f"{loaded} loaded")
    if "nozzle" in before and req.nozzle is not None:
        parts.append(f"a {req.nozzle:g} mm nozzle")
    if "profile" in before and req.profile:
        parts.append(f"the profile {req.profile}")
    if "tags" in before and req.tags:
        parts.append(f"the {_plural('tag', req.tags)} {', '.join(req.tags)}")
    return f" with {' and '.join(parts)}" if parts else ""


def _reason(
    name: str, req: Requirements, part: Part, left: Sequence[PrinterFacts]
) -> str:
    among = _met_so_far(name, req)
    if name == "material":
        return f"no printer has {req.material} loaded"
    if name == "colour":
        if req.material:
            return f"no printer with {req.material} loaded has it in {req.colour}"
        return f"no printer has {req.colour} loaded"
    if name == "nozzle":
        return f"no printer{among} has a {req.nozzle:g} mm nozzle"
    if name == "profile":
        return f"no printer{among} has the profile {req.profile}"
    if name == "tags":
        return f"no printer{among} has the {_plural('tag', req.tags)} " + ", ".join(
            req.tags
        )
    if name == "volume":
        assert part.box is not None
        size = size_text(part.box)
        if all(p.volume is None for p in left):
            return (
                f"no printer{among} has its build volume set (the part is {size}); "
                "set it in the printer's settings"
            )
        whose = f"of the printers{among}" if among else "no printer's"
        if among:
            return f"the part ({size}) fits no build volume {whose}"
        return f"the part ({size}) fits {whose} build volume"
    return (
        f"its longest command ({part.longest} characters) is longer than the "
        f"firmware of any printer{among} takes"
    )
