"""The worker's loop alone: its CPU per 1,000 lines warm, and with its caches cold.

    python -m bench.loop_cost [--mode advanced_ok] [--evict-kb 8192] [--lines 2000]

bench.streaming measures the worker against a simulator over a pty, where the
simulator's process and the kernel run between two turns of the loop and push the
worker's memory out of the core's caches. This runs the same loop (PrinterWorker,
its database, journal and response log) against a port object in this process that
answers each Marlin line at once, one reply a read: each turn takes one `ok` and
writes one line, as with long lines at 250000 baud (two fit the firmware's 127-byte
buffer, so every host wakes once a line). The clock moves on by one line's wire time
a turn, so the database turns come as often per line as on the wire.

Only the turns are timed (thread CPU time), in alternation: *warm*, nothing else
between turns; *cold*, EVICT_KB of memory written between turns (more than the
core's L2 cache), as the other processes do; *idle*, the thread asleep for a long
line's wire time between turns, as the worker is on the wire (its core idle, or
lent to other work, until the next `ok`). The gap between warm and the other two
is what the loop pays for the memory it touches a turn (code and objects), not for
its instructions; which of cold and idle comes closer to bench.streaming's figure
differs from day to day on a shared machine.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench.case import FLOWS

ROOT = Path(__file__).resolve().parent.parent
#: A long line's time on the wire at 250000 baud (55 bytes): the clock's step a turn.
TURN_SECONDS = 0.0022
_NUMBER = re.compile(rb"N(\d+) ")


class InstantFirmware:
    """A Marlin that answers every line at once; the worker's transport, one reply
    line a read."""

    def __init__(self, *, advanced_ok: bool) -> None:
        self.advanced_ok = advanced_ok
        self.replies: list[bytes] = []
        self.woken = False

    def read(self, timeout: float, *, wake: int | None = None) -> bytes:
        return self.replies.pop(0) if self.replies else b""

    def read_waiting(self) -> bytes:
        return self.read(0.0)

    def write(self, data: bytes) -> None:
        for line in data.splitlines():
            if b"M115" in line:
                self.replies.append(
                    b"FIRMWARE_NAME:Marlin 2.1.2 PROTOCOL_VERSION:1.0 "
                    b"EXTRUDER_COUNT:1\nCap:ADVANCED_OK:%d\n" % self.advanced_ok
                )
            number = _NUMBER.match(line)
            if self.advanced_ok and number:
                self.replies.append(b"ok N%s P15 B3\n" % number[1])
            else:
                self.replies.append(b"ok\n")

    def close(self) -> None:
        pass

    def pulse_dtr(self) -> str:
        return "no DTR line"


def run(
    mode: str, lines: int, evict_kb: int, slug: str, *, idle: bool = False
) -> float:
    """CPU seconds per 1,000 lines of the loop's turns (*evict_kb* > 0: cold;
    *idle*: asleep for TURN_SECONDS between turns)."""
    from jobs.services import enqueue_job
    from printers.models import Printer
    from printers.sample_gcode import long_lines
    from printers.worker import port
    from printers.worker.loop import PrinterWorker

    firmware = InstantFirmware(advanced_ok=mode == "advanced_ok")
    port.SerialTransport = type(  # the worker opens this "port"
        "InstantPort", (), {"open": staticmethod(lambda url, baud: firmware)}
    )
    source = Path(os.environ["PRINTHOST_DATA_DIR"]) / f"{slug}.gcode"
    source.write_text(long_lines(lines + 1000))
    printer = Printer.objects.create(
        name=slug, slug=slug, port="/dev/ttyInstant", baud=250000, firmware="marlin",
        flow=FLOWS[mode], temperature_interval=0, status_interval=0,
    )  # fmt: skip
    enqueue_job(printer, source)
    clock = [1000.0]
    worker = PrinterWorker(printer, clock=lambda: clock[0], alone=True)
    worker.pacer.byte_time = 0.0  # answered at once: nothing to pace
    worker.start()
    junk = bytearray(evict_kb * 1024)
    zeros = bytes(len(junk[::64]))
    spent, first = 0.0, None
    try:
        for _ in range(20 * (lines + 1000)):
            stream = worker.host.current_stream
            if stream is None and first is not None:
                raise RuntimeError("the job ended before the lines were counted")
            if first is None and stream is not None and stream.acked >= 500:
                first, spent = stream.acked, 0.0
            if first is not None and stream.acked - first >= lines:
                return spent / (stream.acked - first) * 1000
            if evict_kb:
                junk[::64] = zeros
            if idle:
                time.sleep(TURN_SECONDS)  # the wire's time: no event to wait for
            clock[0] += TURN_SECONDS
            started = time.thread_time()
            worker.tick()
            spent += time.thread_time() - started
        raise RuntimeError(f"the job did not stream {lines} lines in time")
    finally:
        worker.stop()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mode", choices=sorted(FLOWS), default="advanced_ok")
    parser.add_argument("--lines", type=int, default=2000)
    parser.add_argument("--evict-kb", type=int, default=8192)
    parser.add_argument("--runs", type=int, default=3)
    options = parser.parse_args(argv)
    os.environ["PRINTHOST_DATA_DIR"] = tempfile.mkdtemp(prefix="printhost-loop-")
    for name in ("DATABASE_URL", "REDIS_URL"):
        os.environ.pop(name, None)
    os.environ.setdefault("DJANGO_SETTINGS_MODULE", "printhost.settings")
    sys.path.insert(0, str(ROOT))
    import django

    django.setup()
    from django.core.management import call_command

    call_command("migrate", verbosity=0)
    figures: dict[str, list[float]] = {"warm": [], "cold": [], "idle": []}
    for index in range(options.runs):
        for kind in figures:
            evict = options.evict_kb if kind == "cold" else 0
            slug = f"{kind}-{index}"
            figures[kind].append(
                run(options.mode, options.lines, evict, slug, idle=kind == "idle")
            )
    print(_report(options, figures))
    return 0


def _report(options: Any, figures: dict[str, list[float]]) -> str:
    warm, cold, idle = (min(figures[kind]) for kind in ("warm", "cold", "idle"))
    runs = {k: ", ".join(f"{v:.3f}" for v in vs) for k, vs in figures.items()}
    return (
        f"loop cost, Marlin {options.mode}, one line a turn: cpu/1k warm {warm:.3f} "
        f"({runs['warm']}), cold with {options.evict_kb} KB written between turns "
        f"{cold:.3f} ({runs['cold']}): {cold / warm:.1f} x, idle "
        f"{TURN_SECONDS * 1000:.1f} ms between turns {idle:.3f} ({runs['idle']}): "
        f"{idle / warm:.1f} x"
    )


if __name__ == "__main__":
    raise SystemExit(main())
