"""Printer.link_stats: a real worker over a simulator saves the link's figures."""

from __future__ import annotations

import time
from datetime import datetime

import pytest

from printers.models import Printer
from printers.sample_gcode import segments
from printers.worker.loop import PrinterWorker
from tests.conftest import wait_for

pytestmark = [pytest.mark.django_db, pytest.mark.slow]


def test_a_printing_worker_saves_sane_link_figures_about_once_a_second(
    sim_factory, make_printer, make_job
):
    sim = sim_factory("marlin", "--baud", "250000", "--time-scale", "0")
    printer = make_printer(port=str(sim.link), baud=250000)
    make_job(printer, segments(4000))
    worker = PrinterWorker(printer)
    saved: list[dict] = []

    def printing_for_a_while() -> bool:
        stats = Printer.objects.get(pk=printer.pk).link_stats
        if stats and (not saved or stats != saved[-1]):
            saved.append(stats)
        return len(saved) >= 3 and stats["lines_per_s"] > 0

    def tick_a_fifth_of_a_second() -> None:
        until = time.monotonic() + 0.2
        while time.monotonic() < until:
            worker.tick()

    worker.start()
    started = time.monotonic()
    try:
        wait_for(
            printing_for_a_while, 60, "three saves while printing",
            step=tick_a_fifth_of_a_second,
        )  # fmt: skip
    finally:
        elapsed = time.monotonic() - started
        worker.stop()

    first, last = saved[0], saved[-1]
    assert last["lines_sent"] > first["lines_sent"] > 0
    assert 0 < last["lines_acked"] <= last["lines_sent"]
    assert last["bytes_sent"] > last["lines_sent"] and last["bytes_received"] > 0
    assert 0 < last["link_use"] <= 1
    assert last["lines_per_s"] > 0
    assert last["rtt_ms"] > 0
    assert last["resends"] == last["timeouts"] == 0
    assert last["cpu_s"] > 0
    at, connected = (datetime.fromisoformat(last[k]) for k in ("at", "connected_at"))
    assert connected <= at
    assert len(saved) <= elapsed + 2  # no more than once a second
