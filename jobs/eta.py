"""Progress and remaining time of a running job, from its file's analysis.

The analysis says how long each part of the file should take on this printer;
the print says how long it has really taken so far. As PrintTimeGenius does, the
estimate for the rest is the analysed motion time left, scaled by how fast the
print has run against the model, with the scale trusted more as more of the
print has run. Heating is kept apart: the model's heating waits are taken as they
come (they are not motion, and their error says nothing about the motion's).

The machine runs behind the line the firmware acknowledged: Marlin acknowledges a
move when it enters its planner, which holds IN_FLIGHT (16) of them, so the time
is reckoned from the command that many before (heating from the acknowledged line:
a heating wait is acknowledged when it ends; the layer and filament used follow
the acknowledged line, as the preview does). The planner holds from one second of
moves to several (short perimeter segments, long infill lines): reckoned from the
acknowledged line, the estimate would swing with them, and would leave out the
queue's last seconds of a file that ends waiting for its moves (G4, M400, G28).

The pace is trusted in proportion to the analysed motion done, fully once it
reaches TRUST_AFTER seconds or TRUST_SHARE of the print's whole motion, whichever
comes first. A fifth of a print's motion is a fair sample of its pace: a short
print on a machine that runs steadily faster or slower than the model (an inexact
motion profile, a time-scaled simulator) is corrected by the time a fifth of it
has run, not never. A long print still waits five minutes, so its slow first
layer or a one-off mesh probe does not swing the rest of it.

    estimate = eta.estimate(analysis, line=job.lines_acked, elapsed=seconds)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from jobs.analysis.result import Analysis

#: Motion seconds (analysed) after which the measured pace is fully trusted.
TRUST_AFTER = 300.0
#: Share of the print's analysed motion after which the pace is fully trusted,
#: when it comes before TRUST_AFTER (a short print).
TRUST_SHARE = 0.2
#: The measured pace is never taken beyond these factors (a stall, a skipped wait).
PACE_LIMITS = (0.33, 3.0)
#: Commands acknowledged but not yet run: Marlin's planner holds 16 moves
#: (BLOCK_BUFFER_SIZE) and acknowledges each as it enters; Grbl's (AVR) 16 too.
IN_FLIGHT = 16


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


def trusted_after(motion_seconds: float) -> float:
    """Analysed motion seconds after which a print of *motion_seconds* fully trusts
    its measured pace: TRUST_AFTER, or TRUST_SHARE of its motion if that is less."""
    return min(TRUST_AFTER, TRUST_SHARE * motion_seconds)


def estimate(analysis: Analysis, *, line: int, elapsed: float) -> Estimate:
    """The estimate after *line* commands were acknowledged and *elapsed* seconds."""
    line = max(0, min(line, analysis.commands))
    total = analysis.total_seconds
    # The machine runs IN_FLIGHT commands behind, until the last is acknowledged:
    # then the job is over (printhost ends a job at its last acknowledgement).
    running = line if line >= analysis.commands else max(0, line - IN_FLIGHT)
    heating_done = analysis.heating_at(line)
    motion_done = max(0.0, analysis.seconds_at(running) - analysis.heating_at(running))
    done = motion_done + heating_done
    motion_left = max(0.0, analysis.motion_seconds - motion_done)
    heating_left = max(0.0, analysis.heating_seconds - heating_done)
    measured = max(0.0, elapsed - heating_done)
    pace = 1.0
    trust = 0.0
    if motion_done > 1.0 and measured > 0.0:
        low, high = PACE_LIMITS
        pace = min(max(measured / motion_done, low), high)
        trust = min(1.0, motion_done / trusted_after(analysis.motion_seconds))
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
