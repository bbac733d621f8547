"""One benchmark case in its own process: a simulator, a fresh database, the real worker.

    python -m bench.case '{"firmware": "marlin", "mode": "advanced_ok", ...}'

Prints one JSON line with the measurements. The worker runs in this process so its
CPU time can be measured with process_time(); the simulator is a separate process.
"""

from __future__ import annotations

import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: Printer.flow for each Marlin mode of the bench (GRBL's character counting: auto).
FLOWS = {"ping_pong": "ping_pong", "advanced_ok": "auto", "bytes": "buffered"}


def main() -> int:
    case = json.loads(sys.argv[1])
    data_dir = Path(tempfile.mkdtemp(prefix="printhost-bench-"))
    os.environ["PRINTHOST_DATA_DIR"] = str(data_dir)
    os.environ.pop("DATABASE_URL", None)
    # The live-feed pair publishes every response batch to a real Redis.
    os.environ.pop("REDIS_URL", None)
    if case.get("redis"):
        os.environ["REDIS_URL"] = case["redis"]
        os.environ["PRINTHOST_CHANNEL_PREFIX"] = "printhost-bench"
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
    """Start the simulator, time its round trip, then drive the worker through the file."""
    from printers.simulator.process import start_simulator

    sim = start_simulator(data_dir, case["firmware"], *sim_args(case))
    try:
        text = job_text(case)
        size = mean_wire_line(case, text)
        rtt = round_trip(case, sim, size)
        run = measure_reference if case.get("host") == "reference" else measure
        return {**run(case, sim, data_dir, text), **bound(case, rtt, size)}
    finally:
        sim.stop()


def job_text(case: dict) -> str:
    from printers.sample_gcode import long_lines, segments

    if case["file"] == "segments":
        return segments(case["lines"], cnc=case["firmware"] == "grbl")
    return long_lines(case["lines"])


def mean_wire_line(case: dict, text: str) -> float:
    """Mean bytes per line as the protocol writes them (framing, newline)."""
    from printers.protocol.checksum import format_line
    from printers.sample_gcode import commands_of

    commands = commands_of(text)
    if case["firmware"] == "grbl":
        sizes = [len(c.replace(" ", "")) + 1 for c in commands]
    else:
        sizes = [len(format_line(n, c)) + 1 for n, c in enumerate(commands, 1)]
    return sum(sizes) / len(sizes)


def round_trip(case: dict, sim: object, size: float) -> float:
    """Median ping-pong round trip (s) of a *size*-byte line, with a minimal host.

    This is the link as it is: wire time, latency both ways, and the firmware's
    turnaround (the simulator's timer precision included), which any host pays.
    """
    import statistics

    from printers.transport import SerialTransport

    n = max(4, round(size) - 1)
    if case["firmware"] == "grbl":
        line = ("G0X" + "1" * (n - 3)).encode()[:n] + b"\n"
    else:
        line = ("M117 " + "x" * n)[:n].encode() + b"\n"
    port = SerialTransport.open(str(sim.link), case["baud"] or 115200)
    times = []
    try:
        for _ in range(40):
            start = time.perf_counter()
            port.write(line)
            reply = b""
            while not reply.endswith(b"\n") or b"ok" not in reply:
                reply += port.read(1.0)
            times.append(time.perf_counter() - start)
    finally:
        port.close()
    return statistics.median(times)


def sim_args(case: dict) -> list[str]:
    args = ["--baud", str(case["baud"]), "--latency-ms", str(case["latency_ms"])]
    args += ["--time-scale", "0"]
    if case["firmware"] == "marlin":
        args.append("--advanced-ok" if case["mode"] != "bytes" else "--no-advanced-ok")
    return args


def measure(case: dict, sim: object, data_dir: Path, text: str) -> dict:
    from jobs.models import Job
    from jobs.services import enqueue_job
    from printers.models import Printer
    from printers.worker.loop import PrinterWorker

    grbl = case["firmware"] == "grbl"
    source = data_dir / "bench.gcode"
    source.write_text(text)
    printer = Printer.objects.create(
        name="bench", slug="bench", port=str(sim.link), baud=case["baud"] or 115200,
        firmware=case["firmware"], flow=FLOWS.get(case["mode"], "auto"),
        temperature_interval=0, status_interval=0.2 if grbl else 0,
    )  # fmt: skip
    job = enqueue_job(printer, source)
    worker = PrinterWorker(printer, alone=True)  # as run_printer makes it
    if case.get("log") is False:
        # The logging-cost pair: the same case with the response log switched off.
        worker.log.add = lambda text, kind: 0
    worker.start()
    sent = _count_writes(worker)
    started = cpu0 = None
    deadline = None
    turns = 0
    while True:
        worker.tick()
        turns += 1
        stream = worker.host.current_stream
        if started is None and stream is not None and stream.sent:
            started, cpu0, sent[0] = time.perf_counter(), time.process_time(), 0
            split0 = cpu_split()
            deadline = started + case["max_seconds"]
            turns = 0
        if started is not None and (stream is None or time.perf_counter() > deadline):
            break
    seconds = time.perf_counter() - started
    cpu = time.process_time() - cpu0
    user, system = (
        after - before for after, before in zip(cpu_split(), split0, strict=True)
    )
    acked = (
        stream.acked if stream is not None else Job.objects.get(pk=job.pk).lines_acked
    )
    worker.stop()
    return report(
        case, acked, sent[0], seconds, cpu, wakes=turns, user=user, system=system
    )


def measure_reference(case: dict, sim: object, data_dir: Path, text: str) -> dict:
    """The same file through bench/reference_host.py instead of the worker."""
    from bench import reference_host
    from printers.sample_gcode import commands_of

    done = reference_host.stream(
        sim.link, commands_of(text), firmware=case["firmware"], mode=case["mode"],
        baud=case["baud"], max_seconds=case["max_seconds"],
    )  # fmt: skip
    return report(
        case, done["lines"], done["bytes"], done["seconds"], done["cpu"],
        wakes=done["wakes"], user=done["user"], system=done["system"],
    )  # fmt: skip


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


def cpu_split() -> tuple[float, float]:
    """This process's CPU seconds so far, in user space and in the kernel."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime, usage.ru_stime


def report(case: dict, lines: int, sent: int, seconds: float, cpu: float, *,
           wakes: int, user: float | None = None,
           system: float | None = None) -> dict:  # fmt: skip
    """One case's figures; *wakes*: turns of the host's loop (each one wake-up);
    *user* and *system*: the CPU split between user space and the kernel (the
    kernel's share is the system calls, the rest is the host's own code)."""
    rate = sent / seconds if seconds else 0.0
    link = case["baud"] / 10 if case["baud"] else 0.0
    return {
        **{k: case[k] for k in ("name", "firmware", "mode", "baud", "latency_ms")},
        "lines": lines,
        "seconds": round(seconds, 3),
        "lines_per_s": round(lines / seconds, 1) if seconds else 0.0,
        "bytes_per_s": round(rate, 1),
        "link_use": round(rate / link, 3) if link else None,
        "cpu_s_per_1k_lines": round(cpu / lines * 1000, 4) if lines else None,
        "mean_line_bytes": round(sent / lines, 1) if lines else None,
        "wakes_per_line": round(wakes / lines, 3) if lines else None,
        **{
            f"cpu_{name}_per_1k_lines": round(value / lines * 1000, 4)
            for name, value in (("user", user), ("system", system))
            if value is not None and lines
        },
    }


def bound(case: dict, rtt: float, size: float) -> dict:
    """The best link use any host could reach: min(1, window / (baud/10 x round trip)).

    The window is the firmware's RX buffer (127 bytes) when streaming windowed and
    one line (*size* bytes) for ping-pong; the round trip is measured on the link
    itself by round_trip().
    """
    link = case["baud"] / 10
    window = size if case["mode"] == "ping_pong" else 127
    value = round(min(1.0, window / (link * rtt)), 3) if link else None
    return {"bound": value, "rtt_ms": round(rtt * 1000, 3)}


if __name__ == "__main__":
    sys.exit(main())
