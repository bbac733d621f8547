"""Progress and remaining time of a running job, from its file's analysis.

The analysis says how long each part of the file should take on this printer;
the print says how long it has really taken so far. As PrintTimeGenius does, the
estimate for the rest is the analysed motion time left, scaled by how fast the
print has run against the model, with the scale trusted more as more of the
print has run. Heating is kept apart: the model's heating waits are taken as they
come (they are not motion, and their error says nothing about the motion's).

    estimate = eta.estimate(analysis, line=job.lines_acked, elapsed=seconds)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from jobs.analysis.result import Analysis

#: Motion seconds (analysed) after which the measured pace is fully trusted.
TRUST_AFTER = 300.0
#: The measured pace is never taken beyond these factors (a stall, a skipped wait).
PACE_LIMITS = (0.33, 3.0)


@dataclass(frozen=True, slots=True)
class Estimate:
    """Where a print is, in time, by its analysis."""

    #: 0..100: analysed seconds done over all (heating included).
    progress: float
    #: Seconds left, after the pace correction.
    remaining: float
    #: How fast the print runs against the model (1.0 = as analysed).
    pace: float
    #: "analysis" while the pace is not yet trusted at all, else "mixed-analysis".
    origin: str
    #: 1-based layer and the file's layers (0 when the file has none).
    layer: int
    layers: int
    #: Filament pushed so far (mm, all extruders).
    filament_used: float


def estimate(analysis: Analysis, *, line: int, elapsed: float) -> Estimate:
    """The estimate after *line* commands were acknowledged and *elapsed* seconds."""
    line = max(0, min(line, analysis.commands))
    total = analysis.total_seconds
    done = analysis.seconds_at(line)
    heating_done = analysis.heating_at(line)
    motion_done = max(0.0, done - heating_done)
    motion_left = max(0.0, analysis.motion_seconds - motion_done)
    heating_left = max(0.0, analysis.heating_seconds - heating_done)
    measured = max(0.0, elapsed - heating_done)
    pace = 1.0
    trust = 0.0
    if motion_done > 1.0 and measured > 0.0:
        low, high = PACE_LIMITS
        pace = min(max(measured / motion_done, low), high)
        trust = min(1.0, motion_done / TRUST_AFTER)
    factor = trust * pace + (1.0 - trust)
    remaining = motion_left * factor + heating_left
    layer = analysis.layer_at(line) + 1 if analysis.layers else 0
    return Estimate(
        progress=round(100.0 * done / total, 2) if total > 0 else 0.0,
        remaining=round(remaining, 1),
        pace=round(pace, 3),
        origin="mixed-analysis" if trust > 0 else "analysis",
        layer=max(layer, 0),
        layers=len(analysis.layers),
        filament_used=round(analysis.filament_at(line), 1),
    )
