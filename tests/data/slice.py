"""Remake the slicer outputs in this folder (run by hand; the tests use the files).

    python tests/data/slice.py

Needs Debian's `prusa-slicer` (2.5.0) and `cura-engine` (4.13.0), and the `cura`
package's printer definitions (`fdmprinter.def.json`, `fdmextruder.def.json`) in
the folder named by CURA_DEFINITIONS. The models are made here: a 20 x 20 x 10 mm
box and a cylinder 16 mm across and 6 mm high (PrusaSlicer and Cura, a quarter of
an hour each), and a flat 20 x 20 x 2 mm box (PrusaSlicer alone, the same settings
but an end G-code that parks the head, `PARK`: `prusaslicer-2.5_flat-box.gcode`,
ten layers, five minutes), short enough for the ETA test to print on a time-scaled
simulator (tests/analysis/test_eta_end_to_end.py). Three small boxes (10 x 10 x 1
mm, `prusaslicer-2.5_three-boxes.gcode`, five layers, with label objects and a Z
lift on retract) are the object cancel's file (tests/objects/).

CuraEngine alone leaves the header's placeholders (`;TIME:6666`, `;Filament used:
0m`, `;MINX:...`); Cura's front end fills them from what the engine reports, and
`fill_cura_header` does the same here with the engine's printed figures.
"""

from __future__ import annotations

import math
import os
import re
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).parent
PRUSA = HERE / "prusaslicer-2.5_box-and-cylinder.gcode"
CURA = HERE / "cura-4.13_box.gcode"
FLAT = HERE / "prusaslicer-2.5_flat-box.gcode"
THREE = HERE / "prusaslicer-2.5_three-boxes.gcode"

Triangle = tuple[tuple[float, float, float], ...]


def write_stl(path: Path, triangles: list[Triangle]) -> None:
    """A binary STL with each facet's unit normal. PrusaSlicer reads a file as ASCII
    when the 128 bytes after its header are all below 128: with zero normals, a box
    10 mm wide (10.0 is 00 00 20 41) was refused as a broken ASCII STL. The normals
    do not change the slices (the box and cylinder slice the same with or without)."""
    with path.open("wb") as out:
        out.write(b"\0" * 80 + struct.pack("<I", len(triangles)))
        for triangle in triangles:
            out.write(struct.pack("<3f", *normal(triangle)))
            for vertex in triangle:
                out.write(struct.pack("<3f", *vertex))
            out.write(b"\0\0")


def normal(triangle: Triangle) -> tuple[float, float, float]:
    """The facet's unit normal, by the right-hand rule over its vertices."""
    (ax, ay, az), (bx, by, bz), (cx, cy, cz) = triangle
    u, v = (bx - ax, by - ay, bz - az), (cx - ax, cy - ay, cz - az)
    n = (
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    )
    length = math.sqrt(sum(c * c for c in n)) or 1.0
    return (n[0] / length, n[1] / length, n[2] / length)


def box(size_x: float, size_y: float, size_z: float) -> list[Triangle]:
    v = [(x, y, z) for z in (0, size_z) for y in (0, size_y) for x in (0, size_x)]
    v = [v[0], v[1], v[3], v[2], v[4], v[5], v[7], v[6]]
    faces = [(0, 2, 1), (0, 3, 2), (4, 5, 6), (4, 6, 7), (0, 1, 5), (0, 5, 4),
             (1, 2, 6), (1, 6, 5), (2, 3, 7), (2, 7, 6), (3, 0, 4), (3, 4, 7)]  # fmt: skip
    return [(v[a], v[b], v[c]) for a, b, c in faces]


def cylinder(radius: float, height: float, sides: int = 48) -> list[Triangle]:
    out: list[Triangle] = []
    for i in range(sides):
        a0, a1 = 2 * math.pi * i / sides, 2 * math.pi * (i + 1) / sides
        p0 = (radius * math.cos(a0), radius * math.sin(a0))
        p1 = (radius * math.cos(a1), radius * math.sin(a1))
        out += [
            ((0, 0, 0), (*p1, 0), (*p0, 0)),
            ((0, 0, height), (*p0, height), (*p1, height)),
            ((*p0, 0), (*p1, 0), (*p1, height)),
            ((*p0, 0), (*p1, height), (*p0, height)),
        ]
    return out


#: The flat box's end G-code: the head parks and waits for its moves to end, as on
#: Prusa's own printer profiles, where the generic profile's end homes X (G28 X0).
#: The analysis does not time homing and the simulator does (as a firmware homes:
#: three seconds from the box), which the ETA test would count against the estimate.
PARK = (
    "G1 Z{max_layer_z+10} F720 ; move print head up\n"
    "G1 X0 Y200 F3600 ; park\n"
    "G4 ; wait\n"
    "M104 S0 ; turn off temperature\n"
    "M140 S0 ; turn off heatbed\n"
    "M107 ; turn off fan\n"
    "M84 ; disable motors\n"
)


def prusaslicer(models: list[Path], out: Path, *options: str) -> None:
    subprocess.run(
        ["prusa-slicer", "--export-gcode", "--gcode-flavor", "marlin2",
         "--machine-limits-usage", "emit_to_gcode", "--gcode-label-objects",
         "--layer-height", "0.2", "--first-layer-height", "0.2",
         "--nozzle-diameter", "0.4", "--filament-diameter", "1.75",
         "--filament-density", "1.24", "--filament-type", "PLA",
         "--temperature", "210", "--bed-temperature", "60", "--fill-density", "15%",
         "--skirts", "1", *options, "--merge", *map(str, models), "-o", str(out)],
        check=True, capture_output=True,
    )  # fmt: skip


def cura(model: Path) -> None:
    definitions = Path(os.environ["CURA_DEFINITIONS"])
    settings = {
        "machine_width": 200, "machine_depth": 200, "machine_height": 200,
        "material_diameter": 1.75, "machine_gcode_flavor": "RepRap (Marlin/Sprinter)",
        "layer_height": 0.2, "layer_height_0": 0.2, "infill_sparse_density": 15,
        "material_print_temperature": 210, "material_bed_temperature": 60,
    }  # fmt: skip
    args = ["CuraEngine", "slice", "-v", "-j", str(definitions / "fdmprinter.def.json")]
    for key, value in settings.items():
        args += ["-s", f"{key}={value}"]
    args += ["-e0", "-j", str(definitions / "fdmextruder.def.json")]
    args += ["-e0", "-s", "material_diameter=1.75", "-l", str(model), "-o", str(CURA)]
    done = subprocess.run(args, check=True, capture_output=True, text=True)
    fill_cura_header(CURA, done.stdout + done.stderr)


def fill_cura_header(path: Path, log: str) -> None:
    seconds = int(re.search(r"Print time \(s\): (\d+)", log).group(1))  # type: ignore[union-attr]
    cubic = float(re.search(r"Filament \(mm\^3\): (\d+)", log).group(1))  # type: ignore[union-attr]
    metres = cubic / (math.pi * (1.75 / 2) ** 2) / 1000
    xs, ys, zs = [], [], []
    printing = False
    for line in path.read_text().splitlines():
        printing = printing or line.startswith(";LAYER:0")
        if not printing:
            continue
        if line.startswith("G1 ") and " E" in line:
            words = dict((w[0], w[1:]) for w in line.split() if w[0] in "XYZ")
            if "X" in words:
                xs.append(float(words["X"]))
                ys.append(float(words["Y"]))
        elif line.startswith(("G0 ", "G1 ")) and " Z" in line:
            zs.append(float(line.split(" Z")[1].split()[0]))
    values = {
        "TIME": str(seconds), "Filament used": f" {metres:.5f}m",
        "MINX": f"{min(xs):g}", "MINY": f"{min(ys):g}", "MINZ": "0.2",
        "MAXX": f"{max(xs):g}", "MAXY": f"{max(ys):g}", "MAXZ": f"{max(zs):g}",
    }  # fmt: skip
    text = path.read_text()
    for key, value in values.items():
        text = re.sub(
            rf"^;{re.escape(key)}:.*$", f";{key}:{value}", text, count=1, flags=re.M
        )
    path.write_text(text)


def main() -> int:
    with tempfile.TemporaryDirectory() as folder:
        cube, round_ = Path(folder) / "box.stl", Path(folder) / "cylinder.stl"
        write_stl(cube, box(20, 20, 10))
        write_stl(round_, cylinder(8, 6))
        prusaslicer([cube, round_], PRUSA)
        cura(cube)
        flat = Path(folder) / "flat-box.stl"
        write_stl(flat, box(20, 20, 2))
        prusaslicer([flat], FLAT, "--end-gcode", PARK)
        three_boxes(Path(folder))
    return 0


def three_boxes(folder: Path) -> None:
    """Three objects, each named by its file (`box-a.stl`...), a Z lift on retract
    (the slicer's own hops over the other parts), no skirt: every extrusion
    belongs to an object."""
    models = []
    for name in ("box-a", "box-b", "box-c"):
        model = folder / f"{name}.stl"
        write_stl(model, box(10, 10, 1))
        models.append(model)
    prusaslicer(
        models, THREE, "--end-gcode", PARK, "--retract-lift", "0.4", "--skirts", "0"
    )


if __name__ == "__main__":
    sys.exit(main())
