"""`make bench`, second part: a fault-injection soak on Marlin and on GRBL.

One long job per firmware at 250000 baud, printed by the real worker under
`runhost --no-web`, with the printer's default settings, against a simulator that
breaks things all along the way:

- Marlin: 2 % of received lines corrupted (each is a checksum error and a resend),
  0.5 % of `ok`s lost at random, garbled replies, a `busy:` storm, the port pulled
  and restored, the worker SIGKILLed.
- GRBL: the port pulled and restored and the worker SIGKILLed (GRBL has no line
  numbers or checksums, so a corrupted line there is a wrong move or an error that
  stops the job; lost `ok`s are not recoverable by counting characters).

A pulled port or a killed worker leaves the job `interrupted` (printhost never
restarts one by itself). The soak then checks the line printhost says it stopped at
against what the firmware ran, and queues the rest of the file from where the
firmware stopped as a new job (the file's header first: a firmware that was reset
forgot its units, modes and feed rate), as an operator would. The verdict: the simulator's
record of executed job commands equals the file's commands, nothing lost, nothing
repeated, and the simulator's receive buffer never overflowed.

    python -m bench.soak [--lines N] [--only marlin|grbl]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from printers.sample_gcode import commands_of, segments
from printers.simulator.process import SimulatorProcess, start_simulator
from tests.conftest import job_lines, wait_for
from tests.hosts import Host

BAUD = 250000


@dataclass
class Plan:
    """What to break, and at which share of the job."""

    firmware: str
    sim_args: list[str]
    busy_storm_at: float | None = None
    pull_at: float | None = 0.35
    kill_at: float | None = 0.65


PLANS = {
    "marlin": Plan(
        "marlin",
        # 2 % of received lines corrupted; 0.5 % of oks lost at random; one byte in
        # 20,000 of the replies garbled (a broken ok, Resend or temperature line).
        [
            "--corrupt",
            "0.02",
            "--drop-ok-share",
            "0.005",
            "--noise-to-host",
            "0.00005",
            "--seed",
            "8",
        ],
        busy_storm_at=0.15,
    ),
    "grbl": Plan("grbl", []),
}


@dataclass
class Soak:
    """One firmware's run: the installation, its simulator and what happened."""

    plan: Plan
    host: Host
    sim: SimulatorProcess
    commands: list[str]
    events: list[str] = field(default_factory=list)
    paused_s: float = 0.0
    #: Job lines the firmware should run, in order: the file, plus the file's
    #: header again before each continuation (a reset firmware forgot its modes).
    planned: list[str] = field(default_factory=list)
    #: Job lines run before the newest job started.
    offset: int = 0

    def __post_init__(self) -> None:
        self.planned = list(self.commands)

    @property
    def slug(self) -> str:
        return self.plan.firmware

    def executed(self) -> list[str]:
        lines = job_lines(self.sim)
        if self.plan.firmware == "grbl":
            return [c.replace(" ", "") for c in lines]
        return lines

    def expected(self) -> list[str]:
        if self.plan.firmware == "grbl":
            return [c.replace(" ", "") for c in self.planned]
        return self.planned

    def header(self) -> list[str]:
        """The file's set-up commands (units, modes, feed) before its first move."""
        moves = next(i for i, c in enumerate(self.commands) if c.startswith("G1 X"))
        return self.commands[:moves]

    def job(self) -> tuple[int, str, int, str]:
        """The newest job: id, state, lines acknowledged, message."""
        return self.host.query(
            "SELECT id, state, lines_acked, message FROM jobs_job ORDER BY id DESC"
        )[0]

    def queue(self, commands: list[str], name: str) -> None:
        path = self.host.folder / name
        path.write_text("\n".join(commands) + "\n")
        self.host.manage("add_job", self.slug, str(path))

    def wait_job(self, states: tuple[str, ...], timeout: float) -> tuple:
        try:
            wait_for(lambda: self.job()[1] in states, timeout, f"the job in {states}")
        except AssertionError as error:
            state = self.host.query("SELECT state, state_message FROM printers_printer")
            raise SoakFailed(f"{error}; job {self.job()}, printer {state}") from None
        return self.job()

    def wait_progress(self, share: float, timeout: float = 300) -> None:
        """Until the firmware ran *share* of the file (the record is the truth)."""
        target = int(share * len(self.commands))
        wait_for(
            lambda: len(self.executed()) >= target or self.job()[1] != "printing",
            timeout,
            f"{share:.0%} of the job",
        )

    def resume_after_interruption(self, what: str) -> None:
        """Check printhost's interrupted line against the record; queue the rest."""
        started = time.monotonic()
        job_id, state, acked, message = self.wait_job(("interrupted", "failed"), 120)
        wait_for(
            lambda: self.printer_state() == "waitstart", 60, "waitstart after " + what
        )
        ran = len(self.executed())
        ran_of_job = ran - self.offset
        self.events.append(
            f"{what}: job {job_id} {state} at its line {acked}, the firmware ran "
            f"{ran_of_job} of its lines ({message})"
        )
        if state != "interrupted" or acked > ran_of_job:
            raise SoakFailed(f"after {what}: {state}, at {acked} > ran {ran_of_job}")
        rest = self.header() + self.planned[ran:]
        self.planned = self.planned[:ran] + rest
        self.offset = ran
        self.queue(rest, f"rest-{job_id}.gcode")
        self.host.manage("printer_send", self.slug, "--action", "bed_clear")
        self.wait_job(("printing", "completed"), 60)
        self.paused_s += time.monotonic() - started

    def printer_state(self) -> str:
        return self.host.query("SELECT state FROM printers_printer")[0][0]

    def stats(self) -> dict[str, object]:
        return json.loads(self.sim.control("stats").removeprefix("ok "))

    def resends(self) -> int:
        return self.host.query(
            "SELECT COUNT(*) FROM printers_responseline WHERE text LIKE 'Resend:%'"
        )[0][0]


class SoakFailed(AssertionError):
    """The soak saw the promise broken."""


def run_soak(plan: Plan, lines: int, folder: Path) -> dict[str, object]:
    host = Host(folder)
    host.manage("migrate", "--noinput")
    sim = start_simulator(
        folder,
        plan.firmware,
        "--baud", str(BAUD), "--time-scale", "0", *plan.sim_args,
    )  # fmt: skip
    try:
        return _drive(Soak(plan, host, sim, _job_commands(plan, lines)))
    finally:
        sim.stop()


def _job_commands(plan: Plan, lines: int) -> list[str]:
    return commands_of(segments(lines, cnc=plan.firmware == "grbl"))


def _drive(soak: Soak) -> dict[str, object]:
    plan, host = soak.plan, soak.host
    host.shell(
        "from printers.models import Printer; Printer.objects.create("
        f"name={plan.firmware!r}, slug={soak.slug!r}, firmware={plan.firmware!r}, "
        f"port={str(soak.sim.link)!r}, baud={BAUD}, response_log_limit=10**7)"
    )
    soak.queue(soak.commands, "soak.gcode")
    started = time.monotonic()
    with host.running(web=False):
        soak.wait_job(("printing",), 60)
        if plan.busy_storm_at is not None:
            _busy_storm(soak, plan.busy_storm_at)
        if plan.pull_at is not None:
            _pull_port(soak, plan.pull_at)
        if plan.kill_at is not None:
            _kill_worker(soak, plan.kill_at)
        job_id, state, _, message = soak.wait_job(
            ("completed", "failed", "aborted", "interrupted"), 900
        )
        if state != "completed":
            raise SoakFailed(f"job {job_id} {state}: {message}")
        seconds = time.monotonic() - started
    return _result(soak, seconds)


def _busy_storm(soak: Soak, at: float) -> None:
    """Five stalls of 2 s (busy: keepalives, no ok), each after a bit more progress."""
    for step in range(5):
        soak.wait_progress(at + step * 0.01)
        soak.sim.control("busy 2")
    soak.events.append("busy storm: 5 stalls of 2 s")


def _pull_port(soak: Soak, at: float) -> None:
    soak.wait_progress(at)
    soak.sim.control("close")
    time.sleep(2)  # the port stays away for a while, as a pulled cable does
    soak.sim.control("reopen")
    soak.resume_after_interruption("port pulled for 2 s")


def _kill_worker(soak: Soak, at: float) -> None:
    soak.wait_progress(at)
    owner = soak.host.query("SELECT lease_owner FROM printers_printer")[0][0]
    os.kill(int(owner.split(":")[1]), signal.SIGKILL)
    soak.resume_after_interruption("worker SIGKILLed")


def _result(soak: Soak, seconds: float) -> dict[str, object]:
    executed, expected = soak.executed(), soak.expected()
    stats = soak.stats()
    problems = []
    if executed != expected:
        problems.append(_first_difference(executed, expected))
    if stats.get("dropped_bytes"):
        problems.append(f"the firmware's RX buffer dropped {stats['dropped_bytes']} B")
    streaming = seconds - soak.paused_s
    return {
        "name": f"soak/{soak.plan.firmware}/{BAUD}",
        "firmware": soak.plan.firmware,
        "lines": len(expected),
        "seconds": round(seconds, 1),
        "lines_per_s": round(len(expected) / streaming, 1),
        "resends_per_1k": round(1000 * soak.resends() / len(expected), 1),
        "simulator": stats,
        "events": soak.events,
        "integrity": "OK" if not problems else "; ".join(problems),
    }


def _first_difference(executed: list[str], expected: list[str]) -> str:
    for index, (got, want) in enumerate(zip(executed, expected, strict=False)):
        if got != want:
            return f"line {index + 1}: ran {got!r}, the file has {want!r}"
    return f"ran {len(executed)} job lines, the file has {len(expected)}"


def report(results: list[dict[str, object]]) -> int:
    print("\nFault-injection soak (250000 baud, runhost, the printer's defaults)")
    head = f"{'case':22} {'lines':>7} {'s':>7} {'lines/s':>8} {'resends/1k':>10}  integrity"
    print(head + "\n" + "-" * len(head))
    failed = False
    for r in results:
        if "error" in r:
            print(f"{r['name']:22} ERROR {r['error']}")
            failed = True
            continue
        print(
            f"{r['name']:22} {r['lines']:>7} {r['seconds']:>7.1f} "
            f"{r['lines_per_s']:>8.1f} {r['resends_per_1k']:>10.1f}  {r['integrity']}"
        )
        for event in r["events"]:
            print(f"{'':24}{event}")
        print(f"{'':24}simulator: {json.dumps(r['simulator'])}")
        failed = failed or r["integrity"] != "OK"
    print(
        "\n" + ("FAIL soak: integrity broken" if failed else "PASS soak: integrity OK")
    )
    return 1 if failed else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=30000)
    parser.add_argument("--only", choices=sorted(PLANS), default="")
    parser.add_argument("--out", default="bench-soak.json")
    options = parser.parse_args(argv)
    results = []
    for name, plan in PLANS.items():
        if options.only and name != options.only:
            continue
        with tempfile.TemporaryDirectory(prefix="printhost-soak-") as folder:
            try:
                results.append(run_soak(plan, options.lines, Path(folder)))
            except (SoakFailed, AssertionError, RuntimeError) as error:
                log = Path(folder) / "runhost.log"
                tail = log.read_text().splitlines()[-15:] if log.exists() else []
                print("\n".join(tail), file=sys.stderr)
                results.append({"name": f"soak/{name}/{BAUD}", "error": str(error)})
    Path(options.out).write_text(json.dumps(results, indent=1))
    return report(results)


if __name__ == "__main__":
    sys.exit(main())
