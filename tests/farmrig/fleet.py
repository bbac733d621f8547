"""What a test farm holds: its printers (what each has loaded, its build volume) and
its jobs (a file and what it asks of a printer), made to a size; pure, no Django.

The mix is fixed and repeatable: printer *i* is kind `KINDS[i % len(KINDS)]` on
host `shelf-(i % hosts + 1)`; job *j* is `ASKS[j % len(ASKS)]`. Some jobs any
printer with room takes; others only a few printers meet (PETG loaded, a 0.6 mm
nozzle, the tag `enclosed`, a part only the large printers fit).
`meets` is the harness's own reading of a requirement, written apart from the
product's matcher so the test checks it rather than repeats it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

DATA = Path(__file__).resolve().parent.parent / "data"

#: Build volumes ({"min", "max"} in mm): a Prusa MK3's and a large enclosed printer's.
MK3 = {"min": [0, -4, 0], "max": [250, 210, 210]}
BIG = {"min": [0, 0, 0], "max": [350, 350, 340]}


@dataclass(frozen=True)
class PrinterSpec:
    """One simulated printer: where it runs and what the farm may ask of it."""

    slug: str
    host: str
    material: str
    nozzle: float
    profile: str
    tags: tuple[str, ...] = ()
    volume: dict[str, list[float]] = field(default_factory=lambda: MK3)
    colour: str = "black"

    def fields(self) -> dict[str, Any]:
        """The printer row's farm fields."""
        return {
            "material": self.material,
            "colour": self.colour,
            "nozzle_diameter": self.nozzle,
            "profile": self.profile,
            "tags": list(self.tags),
            "build_volume": self.volume,
        }


@dataclass(frozen=True)
class JobSpec:
    """One farm upload: a file and its requirements (the upload's query fields)."""

    name: str
    file: str
    asks: dict[str, str] = field(default_factory=dict)

    def text(self) -> str:
        return gcode_text(self.file)


#: (slug stem, material, nozzle, profile, tags, volume), cycled over the printers.
KINDS: tuple[tuple[str, str, float, str, tuple[str, ...], dict], ...] = (
    ("mk3", "PLA", 0.4, "MK3S", (), MK3),
    ("mk3", "PETG", 0.4, "MK3S", (), MK3),
    ("voron", "ABS", 0.6, "Voron 2.4", ("enclosed",), BIG),
    ("mk4", "PLA", 0.6, "MK4", ("hardened",), MK3),
    ("mk3", "PLA", 0.4, "MK3S", (), MK3),
    ("mk4", "PETG", 0.4, "MK4", (), MK3),
)

#: (file, requirements), cycled over the jobs. Files: real slicer output from
#: tests/data, and `wide` (generated: a part only the large printers fit).
ASKS: tuple[tuple[str, dict[str, str]], ...] = (
    ("prusaslicer-2.5_flat-box.gcode", {}),
    ("prusaslicer-2.5_three-boxes.gcode", {"material": "PLA"}),
    ("prusaslicer-2.5_flat-box.gcode", {"material": "PETG"}),
    ("prusaslicer-2.5_three-boxes.gcode", {"nozzle": "0.6"}),
    ("wide", {}),
    ("prusaslicer-2.5_three-boxes.gcode", {"tags": "enclosed"}),
    ("prusaslicer-2.5_flat-box.gcode", {"material": "PLA", "nozzle": "0.4"}),
    ("prusaslicer-2.5_three-boxes.gcode", {"profile": "MK4"}),
)

#: Files a full-size farm adds (longer real prints).
LONG_FILES = ("cura-4.13_box.gcode", "prusaslicer-2.5_box-and-cylinder.gcode")


def fleet(printers: int, hosts: int) -> list[PrinterSpec]:
    """*printers* printers spread over *hosts* worker hosts (`shelf-1`...)."""
    out = []
    for i in range(printers):
        stem, material, nozzle, profile, tags, volume = KINDS[i % len(KINDS)]
        out.append(
            PrinterSpec(
                slug=f"{stem}-{i + 1:02d}",
                host=f"shelf-{i % hosts + 1}",
                material=material,
                nozzle=nozzle,
                profile=profile,
                tags=tags,
                volume=volume,
            )
        )
    return out


def job_mix(
    count: int, printers: list[PrinterSpec], *, long: bool = False, mixed: bool = True
) -> list[JobSpec]:
    """*count* jobs cycling through `ASKS` (with *long*, every third job's file is one
    of `LONG_FILES`); each is met by at least one of *printers*.

    Not *mixed*: no job asks anything and none is `wide`, so every printer can take
    any job and one job a printer all print at once (a fault test cuts them all
    mid-print; with requirements a few jobs wait for a busy printer that meets them).
    """
    jobs = []
    for j in range(count):
        file, asks = ASKS[j % len(ASKS)]
        if not mixed:
            file, asks = (ASKS[0][0] if file == "wide" else file), {}
        if long and j % 3 == 2 and file != "wide":
            file = LONG_FILES[(j // 3) % len(LONG_FILES)]
        job = JobSpec(f"job{j + 1:02d}-{Path(file).stem}.gcode", file, dict(asks))
        if not any(meets(job.asks, p, extent(file)) for p in printers):
            raise ValueError(f"no printer of the fleet meets {job}")
        jobs.append(job)
    return jobs


def meets(asks: dict[str, str], printer: PrinterSpec, box: Box | None) -> bool:
    """*printer* holds what *asks* names and its volume holds *box*."""
    same = lambda a, b: a.strip().casefold() == b.strip().casefold()
    if "material" in asks and not same(asks["material"], printer.material):
        return False
    if "nozzle" in asks and abs(float(asks["nozzle"]) - printer.nozzle) > 1e-6:
        return False
    if "profile" in asks and not same(asks["profile"], printer.profile):
        return False
    held = {t.casefold() for t in printer.tags}
    wanted = [t for t in asks.get("tags", "").split(",") if t]
    if any(t.strip().casefold() not in held for t in wanted):
        return False
    return box is None or inside(box, printer.volume)


Box = tuple[list[float], list[float]]


def inside(box: Box, volume: dict[str, list[float]]) -> bool:
    low, high = box
    return all(
        low[a] >= volume["min"][a] - 0.01 and high[a] <= volume["max"][a] + 0.01
        for a in range(3)
    )


def extent(file: str) -> Box:
    """Every G0/G1 position the file reaches (a box at least the analysis' size)."""
    low, high = [math.inf] * 3, [-math.inf] * 3
    position = [0.0, 0.0, 0.0]
    for raw in gcode_text(file).splitlines():
        words = raw.split(";", 1)[0].split()
        if not words or words[0] not in ("G0", "G1"):
            continue
        for word in words[1:]:
            axis = "XYZ".find(word[0])
            if axis >= 0:
                position[axis] = float(word[1:])
        for axis in range(3):
            low[axis] = min(low[axis], position[axis])
            high[axis] = max(high[axis], position[axis])
    return low, high


_TEXTS: dict[str, str] = {}


def gcode_text(file: str) -> str:
    """A file's text: one of tests/data, or `wide` (generated)."""
    if file not in _TEXTS:
        _TEXTS[file] = wide_part() if file == "wide" else (DATA / file).read_text()
    return _TEXTS[file]


def wide_part(loops: int = 12, side: float = 280.0, step: float = 10.0) -> str:
    """A 280 mm square outline, one 0.2 mm layer a loop, in 10 mm segments at
    50 mm/s (0.2 s a line, like the slicer files): only a large printer fits it."""
    lines = ["; generated: a wide part", "G28", "G90", "M83", "G1 Z0.2 F600"]
    low = 30.0
    corners = [
        (low, low),
        (low + side, low),
        (low + side, low + side),
        (low, low + side),
    ]
    lines.append(f"G0 X{low:g} Y{low:g} F6000")
    for layer in range(loops):
        lines.append(f"G1 Z{0.2 * (layer + 1):.1f} F600")
        for (x0, y0), (x1, y1) in zip(corners, corners[1:] + corners[:1], strict=True):
            n = round(math.dist((x0, y0), (x1, y1)) / step)
            for k in range(1, n + 1):
                x, y = x0 + (x1 - x0) * k / n, y0 + (y1 - y0) * k / n
                lines.append(f"G1 X{x:.2f} Y{y:.2f} E0.45 F3000")
    lines.append("M84")
    return "\n".join(lines) + "\n"
