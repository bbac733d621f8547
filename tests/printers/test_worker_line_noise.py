"""Line noise in every firmware's wording never fails a job; nothing is lost or repeated."""

from __future__ import annotations

import pytest

from jobs.models import Job
from printers.sample_gcode import segments
from printers.worker.loop import PrinterWorker
from tests.printers.stream_checks import USER_DEFAULTS, assert_streamed_exactly, run_job

pytestmark = [pytest.mark.django_db, pytest.mark.slow]


def stream(sim_factory, make_printer, make_job, lines: int, *sim_args: str):
    text = segments(lines)
    sim = sim_factory(
        "marlin", "--baud", "115200", "--time-scale", "0", "--no-advanced-ok",
        "--no-emergency-parser", *sim_args,
    )  # fmt: skip
    printer = make_printer(port=str(sim.link), baud=115200, **USER_DEFAULTS)
    worker = PrinterWorker(printer)
    job = run_job(worker, make_job(printer, text), timeout=120)
    return sim, text, job, worker


@pytest.mark.parametrize(
    ("dialect", "fault"),
    [
        ("marlin", "--noise-to-firmware"),
        ("prusa", "--noise-to-firmware"),
        ("repetier", "--noise-to-firmware"),
        # Smoothieware runs a line without N unchecked, so the tail of a line
        # split by noise would run: its lines are damaged inside instead.
        ("smoothieware", "--corrupt"),
    ],
)
def test_noise_towards_the_firmware_is_recovered_in_each_dialect(
    sim_factory, make_printer, make_job, dialect, fault
):
    # 1 % of bytes garbled: lines split in two, merged, damaged; errors without
    # Resend (Prusa's "No Line Number with checksum"), Resend without ok (rs).
    share = "0.01" if fault == "--noise-to-firmware" else "0.2"
    sim, text, job, worker = stream(
        sim_factory, make_printer, make_job, 150,
        "--dialect", dialect, fault, share, "--seed", "5",
    )  # fmt: skip
    assert job.state == Job.State.COMPLETED, job.message
    assert_streamed_exactly(sim, text)
    assert worker.protocol.resends > 0


def test_noise_both_ways_never_fails_the_job(sim_factory, make_printer, make_job):
    sim, text, job, worker = stream(
        sim_factory, make_printer, make_job, 150,
        "--noise-to-firmware", "0.01", "--noise-to-host", "0.01", "--seed", "11",
    )  # fmt: skip
    assert job.state == Job.State.COMPLETED, job.message
    assert_streamed_exactly(sim, text)


def test_ok_before_resend_costs_no_timeouts(sim_factory, make_printer, make_job):
    sim, text, job, worker = stream(
        sim_factory, make_printer, make_job, 200,
        "--ok-before-resend", "--corrupt", "0.05", "--seed", "3",
    )  # fmt: skip
    assert job.state == Job.State.COMPLETED, job.message
    assert_streamed_exactly(sim, text)
    assert worker.protocol.resends > 0
    assert worker.protocol.timeouts == 0


@pytest.mark.parametrize("style", ["echo", "raw"])
def test_firmware_echoing_every_line_streams_correctly(
    sim_factory, make_printer, make_job, style
):
    sim, text, job, worker = stream(
        sim_factory, make_printer, make_job, 200, "--echo-lines", style,
        "--corrupt", "0.02", "--seed", "4",
    )  # fmt: skip
    assert job.state == Job.State.COMPLETED, job.message
    assert_streamed_exactly(sim, text)
    assert worker.protocol.timeouts == 0
