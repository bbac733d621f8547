"""One benchmark case in its own process: a simulator, a fresh database, the real worker.

    python -m bench.case '{"firmware": "marlin", "mode": "advanced_ok", ...}'

Prints one JSON line with the measurements. The worker runs in this process so its
CPU time can be measured with process_time(); the simulator is a separate process.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: Ack bytes per line: "ok\n", or ADVANCED_OK's "ok N12345 P15 B3\n".
ACK_BYTES = {"advanced_ok": 18}


def main() -> int:
    case = json.loads(sys.argv[1])
    data_dir = Path(tempfile.mkdtemp(prefix="printhost-bench-"))
    os.environ["PRINTHOST_DATA_DIR"] = str(data_dir)
    os.environ.pop("DATABASE_URL", None)
    os.environ.setdefault("DJANGO_SETTINGS_MODULE", "printhost.settings")
    sys.path.insert(0, str(ROOT))
    import django

    django.setup()
    from django.core.management import call_command

    call_command("migrate", verbosity=0)
    result = run_case(case, data_dir)
    print(json.dumps(result), flush=True)
    return 0


def run_case(case: dict, data_dir: Path) -> dict:
    """Start the simulator, queue the file, drive the worker until done or the cap."""
    from tests.conftest import start_sim

    sim = start_sim(data_dir, case["firmware"], *sim_args(case))
    try:
        return measure(case, sim, data_dir)
    finally:
        sim.stop()


def sim_args(case: dict) -> list[str]:
    args = ["--baud", str(case["baud"]), "--latency-ms", str(case["latency_ms"])]
    args += ["--time-scale", "0"]
    if case["firmware"] == "marlin":
        args.append("--advanced-ok" if case["mode"] != "bytes" else "--no-advanced-ok")
    return args


def measure(case: dict, sim: object, data_dir: Path) -> dict:
    from jobs.models import Job
    from jobs.services import enqueue_job
    from printers.models import Printer
    from printers.sample_gcode import long_lines, segments
    from printers.worker.loop import PrinterWorker

    grbl = case["firmware"] == "grbl"
    text = (
        segments(case["lines"], cnc=grbl)
        if case["file"] == "segments"
        else long_lines(case["lines"])
    )
    source = data_dir / "bench.gcode"
    source.write_text(text)
    flow = {"ping_pong": "ping_pong", "advanced_ok": "auto", "bytes": "buffered"}
    printer = Printer.objects.create(
        name="bench", slug="bench", port=str(sim.link), baud=case["baud"] or 115200,
        firmware=case["firmware"], flow=flow.get(case["mode"], "auto"),
        temperature_interval=0, status_interval=0.2 if grbl else 0,
    )  # fmt: skip
    job = enqueue_job(printer, source)
    worker = PrinterWorker(printer)
    worker.start()
    sent = _count_writes(worker)
    started = cpu0 = None
    deadline = None
    while True:
        worker.tick()
        stream = worker.host.current_stream
        if started is None and stream is not None and stream.sent:
            started, cpu0, sent[0] = time.perf_counter(), time.process_time(), 0
            deadline = started + case["max_seconds"]
        if started is not None and (stream is None or time.perf_counter() > deadline):
            break
    seconds = time.perf_counter() - started
    cpu = time.process_time() - cpu0
    acked = (
        stream.acked if stream is not None else Job.objects.get(pk=job.pk).lines_acked
    )
    worker.stop()
    return report(case, acked, sent[0], seconds, cpu, text)


def _count_writes(worker: object) -> list[int]:
    """Count the bytes the worker writes to the port (wrapping the transport's write)."""
    count = [0]
    while worker.transport is None:
        worker.tick()
    write = worker.transport.write

    def counting(data: bytes) -> None:
        count[0] += len(data)
        write(data)

    worker.transport.write = counting
    return count


def report(
    case: dict, lines: int, sent: int, seconds: float, cpu: float, text: str
) -> dict:
    rate = sent / seconds if seconds else 0.0
    link = case["baud"] / 10 if case["baud"] else 0.0
    mean_line = sent / lines if lines else 0.0
    return {
        **{k: case[k] for k in ("name", "firmware", "mode", "baud", "latency_ms")},
        "lines": lines,
        "seconds": round(seconds, 3),
        "lines_per_s": round(lines / seconds, 1) if seconds else 0.0,
        "bytes_per_s": round(rate, 1),
        "link_use": round(rate / link, 3) if link else None,
        "bound": bound(case, mean_line) if link else None,
        "cpu_s_per_1k_lines": round(cpu / lines * 1000, 4) if lines else None,
    }


def bound(case: dict, mean_line: float) -> float:
    """The best link use any host could reach: min(1, window / (baud/10 x round trip)).

    Round trip = latency both ways + sending one line + sending its ack. The window
    is the firmware's RX buffer (127 bytes) when windowed, one line for ping-pong.
    """
    link = case["baud"] / 10
    ack = ACK_BYTES.get(case["mode"], 3)
    rtt = 2 * case["latency_ms"] / 1000 + (mean_line + ack) / link
    window = mean_line if case["mode"] == "ping_pong" else 127
    return round(min(1.0, window / (link * rtt)), 3)


if __name__ == "__main__":
    sys.exit(main())
