"""The committed slicer outputs (tests/data) and Prusa binary G-code made from them.

The binary files are made with libbgcode's own converter (pybgcode, Prusa's library)
and PrusaSlicer's default settings: heatshrink 12/4 and MeatPack keeping comments for
the G-code, Deflate for the slicer's metadata, CRC32 on every block.
"""

from __future__ import annotations

from pathlib import Path

import pybgcode

DATA = Path(__file__).resolve().parent / "data"
PRUSA = DATA / "prusaslicer-2.5_box-and-cylinder.gcode"
CURA = DATA / "cura-4.13_box.gcode"


def to_binary(text_file: Path, out: Path) -> Path:
    """*text_file* converted to binary G-code as PrusaSlicer 2.7+ writes it."""
    source, target = pybgcode.open(str(text_file), "r"), pybgcode.open(str(out), "wb")
    try:
        result = pybgcode.from_ascii_to_binary(source, target, pybgcode.get_config())
    finally:
        pybgcode.close(source)
        pybgcode.close(target)
    if result != pybgcode.EResult.Success:
        raise ValueError(pybgcode.translate_result(result))
    return out
