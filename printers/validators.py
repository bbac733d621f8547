"""What a printer's settings must hold: the validators of Printer's fields.

Migrations name them as `printers.models.validate_*`, which models.py keeps.
"""

from __future__ import annotations

import math
from pathlib import Path

from django.conf import settings
from django.core.exceptions import ValidationError

from printers.ports import PortRefused, check_configured_port, simulator_paths_outside

__all__ = [
    "validate_build_volume",
    "validate_motion_profile",
    "validate_port",
    "validate_script",
    "validate_simulator",
    "validate_tags",
]


def validate_port(value: str) -> None:
    """A port printhost may open (`printers.ports`): device paths, listed hosts."""
    try:
        check_configured_port(value)
    except PortRefused as error:
        raise ValidationError(str(error), code="port") from None


def validate_simulator(value: str) -> None:
    """Simulator arguments whose --record, --link and --control stay in the data dir."""
    if not value:
        return
    outside = simulator_paths_outside(value, data_dir=Path(settings.DATA_DIR))
    if outside:
        raise ValidationError(
            f"{'; '.join(outside)}: simulator files must be inside the data "
            "directory (PRINTHOST_DATA_DIR)",
            code="simulator",
        )


def validate_motion_profile(value: object) -> None:
    """A motion profile the analyser understands (`MotionLimits.from_profile`)."""
    from jobs.analysis.limits import BadProfile, MotionLimits

    if not isinstance(value, dict):
        raise ValidationError("an object of motion settings", code="motion")
    try:
        MotionLimits.from_profile(value)
    except BadProfile as error:
        raise ValidationError(str(error), code="motion") from None


#: The farthest a build volume's corner may lie from the origin (mm): 10 m.
BUILD_VOLUME_REACH = 10_000


def validate_build_volume(value: object) -> None:
    """{} (unknown) or {"min": [x, y, z], "max": [x, y, z]} in mm, min below max,
    each within BUILD_VOLUME_REACH of the origin (JSON's Infinity would make
    every part fit, and the farm's size order meaningless)."""
    if value in ({}, None):
        return
    if not isinstance(value, dict) or set(value) != {"min", "max"}:
        raise ValidationError(
            'the build volume is {"min": [x, y, z], "max": [x, y, z]} in mm, or {}',
            code="build_volume",
        )
    corners = [value["min"], value["max"]]
    if not all(
        isinstance(c, list)
        and len(c) == 3
        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in c)
        for c in corners
    ):
        raise ValidationError(
            "min and max are three numbers each (x, y, z in mm)", code="build_volume"
        )
    if not all(
        math.isfinite(v) and abs(v) <= BUILD_VOLUME_REACH for c in corners for v in c
    ):
        raise ValidationError(
            f"each number is in mm, at most {BUILD_VOLUME_REACH} from 0",
            code="build_volume",
        )
    if not all(lo < hi for lo, hi in zip(*corners, strict=True)):
        raise ValidationError(
            "each of min's numbers must be below max's", code="build_volume"
        )


def validate_tags(value: object) -> None:
    """A list of short words (farm requirements match them)."""
    if not isinstance(value, list) or not all(
        isinstance(tag, str) and 0 < len(tag) <= 40 for tag in value
    ):
        raise ValidationError(
            "tags are a list of words of 1 to 40 characters", code="tags"
        )


def validate_script(value: str) -> None:
    """Every line of a script is one the firmware's protocol takes (printable ASCII).

    Scripts are sent as written (comments removed), so a line the protocol would
    refuse is refused here, with its number, instead of failing around a job.
    """
    from jobs.gcode import command_problem
    from printers.protocol.checksum import clean_line

    for number, raw in enumerate(value.splitlines(), start=1):
        text = clean_line(raw)
        problem = command_problem(text) if text else ""
        if problem:
            raise ValidationError(f"line {number}: {problem}", code="script")
