"""Remaining time by the analysis, corrected by the measured pace, heating apart."""

from __future__ import annotations

from pathlib import Path

import pytest

from jobs.analysis.analyser import Analyser
from jobs.analysis.result import Analysis
from jobs.eta import TRUST_AFTER, estimate

PRUSA = (
    Path(__file__).resolve().parent.parent
    / "data"
    / "prusaslicer-2.5_box-and-cylinder.gcode"
)


@pytest.fixture(scope="module")
def analysis() -> Analysis:
    analyser = Analyser()
    analyser.feed(PRUSA.read_bytes())
    return analyser.finish()


def line_at_share(analysis: Analysis, share: float) -> int:
    """The first command at which *share* of the analysed time has passed."""
    target = share * analysis.total_seconds
    return next(n for n in range(analysis.commands) if analysis.seconds_at(n) >= target)


@pytest.mark.parametrize("share", [0.25, 0.5, 0.75])
def test_a_print_running_as_analysed_gets_the_analysed_rest(
    analysis: Analysis, share: float
) -> None:
    line = line_at_share(analysis, share)
    elapsed = analysis.seconds_at(line)
    found = estimate(analysis, line=line, elapsed=elapsed)
    assert found.remaining == pytest.approx(analysis.total_seconds - elapsed, rel=0.01)
    assert found.progress == pytest.approx(100 * share, abs=0.5)
    assert found.pace == pytest.approx(1.0, abs=0.01)
    assert found.origin == "mixed-analysis"
    assert 1 <= found.layer <= found.layers == 50


def test_a_print_running_slower_is_expected_to_stay_slower(analysis: Analysis) -> None:
    """Half way through a print that ran 20 % slower than the model (after heating
    as analysed), the rest is predicted 20 % slower too."""
    line = line_at_share(analysis, 0.5)
    heating = analysis.heating_at(line)
    motion = analysis.seconds_at(line) - heating
    assert motion > TRUST_AFTER
    found = estimate(analysis, line=line, elapsed=heating + 1.2 * motion)
    motion_left = analysis.motion_seconds - motion
    heating_left = analysis.heating_seconds - heating
    assert found.pace == pytest.approx(1.2, abs=0.01)
    assert found.remaining == pytest.approx(1.2 * motion_left + heating_left, rel=0.01)


def test_early_in_a_print_the_pace_is_hardly_trusted(analysis: Analysis) -> None:
    """Right after heating, a slow first minute (the first layer runs slowly on
    purpose on many printers) must not triple the whole estimate."""
    line = line_at_share(analysis, 0.12)
    heating = analysis.heating_at(line)
    motion = analysis.seconds_at(line) - heating
    assert 0 < motion < TRUST_AFTER / 4
    found = estimate(analysis, line=line, elapsed=heating + 3 * motion)
    plain = analysis.total_seconds - analysis.seconds_at(line)
    assert found.remaining < 1.5 * plain


def test_before_the_first_move_only_the_analysis_speaks(analysis: Analysis) -> None:
    found = estimate(analysis, line=0, elapsed=5)
    assert found.origin == "analysis"
    assert found.remaining == pytest.approx(analysis.total_seconds, rel=0.001)
    assert found.progress == 0
    assert found.layer == 0
    assert found.filament_used == 0


def test_a_finished_print_has_nothing_left(analysis: Analysis) -> None:
    found = estimate(analysis, line=analysis.commands, elapsed=analysis.total_seconds)
    assert found.remaining == 0
    assert found.progress == 100
    assert found.layer == 50
    assert found.filament_used == pytest.approx(analysis.filament_total, abs=0.1)
