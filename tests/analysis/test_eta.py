"""Remaining time by the analysis, corrected by the measured pace, heating apart."""

from __future__ import annotations

from pathlib import Path

import pytest

from jobs.analysis.analyser import Analyser
from jobs.analysis.result import Analysis
from jobs.eta import IN_FLIGHT, TRUST_AFTER, TRUST_SHARE, estimate, trusted_after

DATA = Path(__file__).resolve().parent.parent / "data"
#: A quarter of an hour of motion (50 layers).
PRUSA = DATA / "prusaslicer-2.5_box-and-cylinder.gcode"
#: Five minutes of motion (10 layers).
FLAT = DATA / "prusaslicer-2.5_flat-box.gcode"


def analyse(text: bytes) -> Analysis:
    """The file's analysis with a timeline mark every 8 commands (as the Celery task
    marks these files: at least 1024 marks)."""
    analyser = Analyser(stride=8)
    analyser.feed(text)
    return analyser.finish()


@pytest.fixture(scope="module")
def analysis() -> Analysis:
    return analyse(PRUSA.read_bytes())


@pytest.fixture(scope="module")
def short() -> Analysis:
    return analyse(FLAT.read_bytes())


def line_at_share(analysis: Analysis, share: float) -> int:
    """The first command at which *share* of the analysed time has passed."""
    target = share * analysis.total_seconds
    return next(n for n in range(analysis.commands) if analysis.seconds_at(n) >= target)


def line_at_motion(analysis: Analysis, seconds: float) -> int:
    """The first command at which *seconds* of analysed motion have passed."""
    return next(
        n
        for n in range(analysis.commands)
        if analysis.seconds_at(n) - analysis.heating_at(n) >= seconds
    )


def machine_at(analysis: Analysis, line: int) -> tuple[float, float]:
    """Analysed (heating, motion) seconds a machine that runs as analysed has done
    when *line* commands are acknowledged: the heating waits up to that line, the
    motion up to IN_FLIGHT commands before it (those wait in its planner)."""
    running = max(0, line - IN_FLIGHT)
    motion = analysis.seconds_at(running) - analysis.heating_at(running)
    return analysis.heating_at(line), motion


@pytest.mark.parametrize("share", [0.25, 0.5, 0.75])
def test_a_print_running_as_analysed_gets_the_analysed_rest(
    analysis: Analysis, share: float
) -> None:
    """The machine runs the moves in its planner after the firmware acknowledged
    them: the time done is reckoned IN_FLIGHT commands behind the acknowledged
    line, and the rest includes the moves still queued."""
    line = line_at_share(analysis, share) + IN_FLIGHT
    heating, motion = machine_at(analysis, line)
    elapsed = heating + motion
    found = estimate(analysis, line=line, elapsed=elapsed)
    assert found.remaining == pytest.approx(analysis.total_seconds - elapsed, rel=0.01)
    assert found.progress == pytest.approx(100 * share, abs=0.5)
    assert found.pace == pytest.approx(1.0, abs=0.01)
    assert found.origin == "mixed-analysis"
    assert 1 <= found.layer <= found.layers == 50


def test_the_moves_in_the_planner_are_still_to_run(analysis: Analysis) -> None:
    """Half way, the rest is the analysed time from IN_FLIGHT commands before the
    acknowledged line: more than from the line itself by the queued moves' time."""
    line = line_at_share(analysis, 0.5)
    heating, motion = machine_at(analysis, line)
    found = estimate(analysis, line=line, elapsed=heating + motion)
    from_the_line = analysis.total_seconds - analysis.seconds_at(line)
    queued = analysis.seconds_at(line) - heating - motion
    assert queued > 0.5
    assert found.remaining == pytest.approx(from_the_line + queued, abs=0.2)


def test_a_print_running_slower_is_expected_to_stay_slower(analysis: Analysis) -> None:
    """Half way through a print that ran 20 % slower than the model (after heating
    as analysed), the rest is predicted 20 % slower too."""
    line = line_at_share(analysis, 0.5)
    heating, motion = machine_at(analysis, line)
    assert motion > TRUST_AFTER
    found = estimate(analysis, line=line, elapsed=heating + 1.2 * motion)
    motion_left = analysis.motion_seconds - motion
    heating_left = analysis.heating_seconds - heating
    assert found.pace == pytest.approx(1.2, abs=0.01)
    assert found.remaining == pytest.approx(1.2 * motion_left + heating_left, rel=0.01)


def test_on_a_long_print_a_slow_first_minute_is_hardly_trusted() -> None:
    """Right after heating, a slow first minute (the first layer runs slowly on
    purpose on many printers) must not triple the whole estimate of a long print:
    the quarter-hour slice printed three times over is 45 minutes of motion, whose
    pace is fully trusted only after TRUST_AFTER seconds, not a fifth of it."""
    long = analyse(PRUSA.read_bytes() * 3)
    assert TRUST_SHARE * long.motion_seconds > TRUST_AFTER
    line = line_at_motion(long, 60.0) + IN_FLIGHT
    heating, motion = machine_at(long, line)
    assert 60 <= motion < 65
    found = estimate(long, line=line, elapsed=heating + 3 * motion)
    plain = long.total_seconds - heating - motion
    assert found.pace == pytest.approx(3.0)
    assert found.remaining < 1.5 * plain


def test_a_short_print_trusts_its_pace_once_a_fifth_of_it_has_run(
    short: Analysis,
) -> None:
    """A five-minute print on a machine that runs steadily twice as fast as the
    model (an inexact motion profile, a simulator whose time is scaled) is told
    the right rest a quarter into its motion: a fifth of it is a fair sample of
    its pace."""
    assert trusted_after(short.motion_seconds) < TRUST_AFTER
    line = line_at_motion(short, 0.25 * short.motion_seconds) + IN_FLIGHT
    heating, motion = machine_at(short, line)
    assert motion > TRUST_SHARE * short.motion_seconds
    found = estimate(short, line=line, elapsed=heating + 0.5 * motion)
    motion_left = short.motion_seconds - motion
    heating_left = short.heating_seconds - heating
    assert found.pace == pytest.approx(0.5, abs=0.01)
    assert found.remaining == pytest.approx(0.5 * motion_left + heating_left, rel=0.01)


def test_before_a_fifth_of_a_short_print_its_pace_is_trusted_in_proportion(
    short: Analysis,
) -> None:
    """Half way to a fifth of its motion, the pace counts half: at 0.5 of the
    model's pace, the rest is three quarters of the analysed motion left."""
    line = line_at_motion(short, TRUST_SHARE / 2 * short.motion_seconds)
    line += IN_FLIGHT
    heating, motion = machine_at(short, line)
    trust = motion / (TRUST_SHARE * short.motion_seconds)
    assert trust == pytest.approx(0.5, abs=0.05)
    found = estimate(short, line=line, elapsed=heating + 0.5 * motion)
    motion_left = short.motion_seconds - motion
    heating_left = short.heating_seconds - heating
    expected = motion_left * (trust * 0.5 + (1 - trust)) + heating_left
    assert found.remaining == pytest.approx(expected, rel=0.01)


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
