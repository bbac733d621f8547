"""Stream integrity with the settings a user gets, faults both ways: nothing lost or repeated.

Every test compares the simulator's record with the file line by line and fails
when the simulator's RX buffer dropped a byte (tests.printers.stream_checks).
"""

from __future__ import annotations

import pytest

from jobs.models import Job
from printers.sample_gcode import segments
from printers.worker.loop import PrinterWorker
from tests.printers.stream_checks import USER_DEFAULTS, assert_streamed_exactly, run_job

pytestmark = [pytest.mark.django_db, pytest.mark.slow]

#: The simulator as a user's board: no ADVANCED_OK, no emergency parser.
BOARD = ("--baud", "115200", "--no-advanced-ok", "--no-emergency-parser")


def stream(sim_factory, make_printer, make_job, lines: int, *sim_args: str):
    text = segments(lines)
    sim = sim_factory("marlin", *BOARD, *sim_args)
    printer = make_printer(port=str(sim.link), baud=115200, **USER_DEFAULTS)
    worker = PrinterWorker(printer)
    job = run_job(worker, make_job(printer, text), timeout=120)
    return sim, text, job, worker


def test_lost_oks_cost_no_ack_timeout(sim_factory, make_printer, make_job):
    # One ok in ten lost, moves in real time: each used to cost the full ack
    # timeout (10 s); a numbered M105 probe (T6) settles it in about a second.
    sim, text, job, worker = stream(
        sim_factory, make_printer, make_job, 100,
        "--time-scale", "1", "--drop-ok-every", "10",
    )  # fmt: skip
    assert job.state == Job.State.COMPLETED, job.message
    assert_streamed_exactly(sim, text)
    assert worker.protocol.timeouts == 0
    assert worker.protocol.probes > 0


@pytest.mark.parametrize("dialect", ["marlin", "repetier", "smoothieware"])
def test_garbled_and_lost_replies_in_each_dialect(
    sim_factory, make_printer, make_job, dialect
):
    sim, text, job, worker = stream(
        sim_factory, make_printer, make_job, 200,
        "--time-scale", "0", "--dialect", dialect, "--noise-to-host", "0.01",
        "--drop-ok-every", "25", "--seed", "21",
    )  # fmt: skip
    assert job.state == Job.State.COMPLETED, job.message
    assert_streamed_exactly(sim, text)


def test_faults_both_ways_with_latency(sim_factory, make_printer, make_job):
    sim, text, job, worker = stream(
        sim_factory, make_printer, make_job, 150,
        "--time-scale", "0", "--latency-ms", "20", "--noise-to-host", "0.005",
        "--noise-to-firmware", "0.005", "--drop-ok-every", "30", "--seed", "8",
    )  # fmt: skip
    assert job.state == Job.State.COMPLETED, job.message
    assert_streamed_exactly(sim, text)


def test_buffered_flow_with_noise_never_overruns_the_rx_buffer(
    sim_factory, make_printer, make_job
):
    text = segments(200)
    sim = sim_factory(
        "marlin", *BOARD, "--time-scale", "0", "--noise-to-firmware", "0.005",
        "--noise-to-host", "0.005", "--seed", "13",
    )  # fmt: skip
    fields = {**USER_DEFAULTS, "flow": "buffered"}
    printer = make_printer(port=str(sim.link), baud=115200, **fields)
    job = run_job(PrinterWorker(printer), make_job(printer, text), timeout=120)
    assert job.state == Job.State.COMPLETED, job.message
    assert_streamed_exactly(sim, text)
