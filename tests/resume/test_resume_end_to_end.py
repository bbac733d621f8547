"""Resume over real ptys: a worker is SIGKILLed mid-print, the printer loses power, and
the resumed run sends the preamble then the rest of the file, nothing lost or
repeated, with the machine where an uninterrupted run would be at that line."""

from __future__ import annotations

import json
import signal
from typing import TYPE_CHECKING

import pytest

from jobs.gcode import command_of
from printers.sample_gcode import commands_of
from printers.worker.journal import Entry, Journal
from tests.conftest import HOST_COMMANDS, Sim, wait_for
from tests.hosts import Host
from tests.resume.prints import cnc_pocket, cnc_zeroed_here, layered_print

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

pytestmark = pytest.mark.slow

#: The firmware stops (busy for good) before this command, counted from its start.
STALL_AT = 700


#: The printer's start script: it opens the first run, never the resumed one (a
#: real one homes Z and probes the bed, with the part on it then).
START_SCRIPT = "M117 printer start script"


def _job_commands(sim: Sim) -> list[tuple[str, str]]:
    """(command, the state it found) of every command but the host's own and the
    start script's."""
    out = []
    for line in sim.recorded():
        text, _, state = line.partition("\t@ ")
        if not text.startswith((*HOST_COMMANDS, START_SCRIPT)):
            out.append((text, state))
    return out


class Interrupted:
    """A job printed until the firmware stalls, its worker SIGKILLed, the printer
    reset (a power cut: position, heaters and modes gone), the job interrupted."""

    def __init__(
        self, tmp_path: Path, sim: Sim, text: str, firmware: str, start: str = ""
    ) -> None:
        self.sim, self.text = sim, text
        host = self.host = Host(tmp_path)
        host.env["PRINTHOST_LEASE_SECONDS"] = "2"
        host.migrate()
        (tmp_path / "job.gcode").write_text(text)
        host.shell(
            "from printers.models import Printer; Printer.objects.create(name='P0', "
            f"slug='p0', port={str(sim.link)!r}, baud=250000, firmware={firmware!r}, "
            f"temperature_interval=0, start_script={start!r})"
        )
        host.manage("add_job", "p0", str(tmp_path / "job.gcode"))
        # The analysis, as the Celery worker makes it (a resume needs it).
        host.shell(
            "from jobs.models import Job; from jobs.analysis_task import run; "
            "run(Job.objects.get().analysis_id)"
        )
        journal = Journal(1, tmp_path / "journal")
        journaled = lambda: (journal.last() or Entry(0, 0, 0, 0)).acked
        first = host.run_printer("p0")
        try:
            wait_for(
                lambda: sim.stats()["executed"] == STALL_AT - 1
                and len(sim.executed()) == STALL_AT - 1
                and journaled() == len(_job_commands(sim)), 60,
                "the firmware to stall and the worker to journal its last ok",
            )  # fmt: skip
            first.send_signal(signal.SIGKILL)
            first.wait(timeout=30)
        finally:
            if first.poll() is None:
                first.kill()
        #: What the machine held before the next line: the uninterrupted state.
        self.state_at_stop = sim.stats()["state"]
        self.before = len(_job_commands(sim))
        assert sim.control("reset") == "ok"  # the power cut
        wait_for(lambda: host.lease_expired(), 30, "the dead worker's lease to expire")
        self.worker = host.run_printer("p0")
        state = lambda: host.query("SELECT state FROM jobs_job")[0][0]
        wait_for(lambda: state() == "interrupted", 60, "the job to be interrupted")

    def resume(self, **choice: int) -> tuple[int, list[str]]:
        """Plan (as the API does), make the plan (as Celery does), start it; wait
        for the resumed run to complete. Returns its start line and preamble."""
        out = self.host.shell(
            "import json; from jobs.models import Job; "
            "from jobs.resume.planning import request_plan, make_plan, start_plan; "
            f"plan = request_plan(Job.objects.get(), **{choice!r}); "
            "make_plan(plan.pk); plan.refresh_from_db(); "
            "resumed = start_plan(plan); "
            "print(json.dumps([plan.line, plan.preamble, resumed.pk]))"
        )
        line, preamble, resumed = json.loads(out.splitlines()[-1])
        state = lambda: self.host.query(
            f"SELECT state, message FROM jobs_job WHERE id = {resumed}"
        )[0]
        try:
            wait_for(lambda: state()[0] not in ("queued", "printing"), 120,
                     "the resumed run to end")  # fmt: skip
        except AssertionError:
            tail = "\n".join(self.sim.recorded()[-5:])
            raise AssertionError(f"{state()}; the record ends:\n{tail}") from None
        assert state()[0] == "completed", state()
        lines_acked = self.host.query(
            f"SELECT lines_acked FROM jobs_job WHERE id = {resumed}"
        )[0][0]
        assert lines_acked == len(commands_of(self.text))
        wait_for(
            lambda: len(self.sim.executed()) == self.sim.stats()["executed"], 10,
            "the simulator's record to hold every command it ran",
        )  # fmt: skip
        cleaned = [command_of(raw.encode()) for raw in preamble.splitlines()]
        return line, [c for c in cleaned if c]

    def close(self) -> None:
        self.worker.send_signal(signal.SIGTERM)
        self.worker.wait(timeout=60)


def _position(state: str) -> list[float]:
    return [float(v) for v in state.split()[:4]]


@pytest.fixture
def marlin_run(tmp_path: Path, sim_factory):
    sim = sim_factory(
        "marlin", "--time-scale", "0", "--baud", "0", "--record-state",
        "--busy-after", str(STALL_AT), "--busy-seconds", "600",
    )  # fmt: skip
    run = Interrupted(tmp_path, sim, layered_print(), "marlin", start=START_SCRIPT)
    yield run
    run.close()


def test_sigkilled_job_resumes_at_its_last_acked_line_after_the_preamble(marlin_run):
    run = marlin_run
    line, preamble = run.resume()
    commands = commands_of(run.text)

    assert line == run.before  # the line after the last one acknowledged
    recorded = _job_commands(run.sim)
    assert [c for c, _ in recorded] == commands[:line] + preamble + commands[line:], (
        "a line was lost or repeated, or the preamble is not between"
    )
    started = [c for c in run.sim.recorded() if c.startswith(START_SCRIPT)]
    assert len(started) == 1, "the start script ran before the resumed run too"
    assert "G28 X Y" in preamble and "G28" not in preamble  # Z is never homed
    assert "M190 S60" in preamble and "M109 T0 S210" in preamble
    assert "M106 P0 S200" in preamble or line < commands.index("M106 S200")
    # The machine at the resume point, as an uninterrupted run had it there.
    found = _position(recorded[line + len(preamble)][1])
    assert found == pytest.approx(_position(run.state_at_stop), abs=1e-4)


def test_a_job_resumes_from_a_chosen_layer(marlin_run):
    run = marlin_run
    first_pass = _job_commands(run.sim)  # the interrupted run: each state recorded
    layer = 2  # printed before the stall; the nozzle goes back down to it
    line, preamble = run.resume(layer=layer)
    commands = commands_of(run.text)

    assert commands[line] == "G1 Z0.6 F600" and line < run.before
    recorded = _job_commands(run.sim)
    assert [c for c, _ in recorded] == (
        commands[: run.before] + preamble + commands[line:]
    )
    found = _position(recorded[run.before + len(preamble)][1])
    assert found == pytest.approx(_position(first_pass[line][1]), abs=1e-4)


def _grbl_resumed(
    tmp_path: Path, sim_factory: Callable[..., Sim], text: str
) -> tuple[Sim, Interrupted, int, list[str]]:
    """*text* run on GRBL until it stalls, then resumed at the stop (a power cut
    between): the simulator, the run, its start line and preamble."""
    sim = sim_factory(
        "grbl", "--time-scale", "0", "--baud", "0", "--record-state",
        "--busy-after", str(STALL_AT), "--busy-seconds", "600",
    )  # fmt: skip
    run = Interrupted(tmp_path, sim, text, "grbl")
    try:
        line, preamble = run.resume()
    finally:
        run.close()
    return sim, run, line, preamble


def test_a_grbl_job_resumes_with_its_modal_state_and_position(tmp_path, sim_factory):
    sim, run, line, preamble = _grbl_resumed(tmp_path, sim_factory, cnc_pocket())
    commands = commands_of(run.text)

    recorded = _job_commands(sim)
    compact = lambda lines: [c.replace(" ", "") for c in lines]  # as GRBL is sent
    assert compact(c for c, _ in recorded) == compact(
        commands[:line] + preamble + commands[line:]
    )
    assert "G55" in preamble and "M3 S12000" in preamble and "M8" in preamble
    # Work position and every modal group ($G: motion, G55, units, distance,
    # feed mode, spindle, coolant, tool, feed, speed) as the uninterrupted run
    # (GRBL's record gives the state a line left: the preamble's last).
    assert recorded[line + len(preamble) - 1][1] == run.state_at_stop


def test_a_grbl_job_that_set_its_own_zero_resumes_in_the_same_place(
    tmp_path, sim_factory
):
    """GRBL forgets a G92 offset when it resets: a preamble in the file's numbers
    alone put the tool at the right work position on the wrong spot of the machine
    (by the offset: a plunge into the stock, or beside it)."""
    sim, run, line, preamble = _grbl_resumed(tmp_path, sim_factory, cnc_zeroed_here())
    assert "G92.1" in preamble and any(c.startswith("G92 X") for c in preamble)
    recorded = _job_commands(sim)
    # Work position, modes and machine position (`MPos:`) as the uninterrupted run.
    assert recorded[line + len(preamble) - 1][1] == run.state_at_stop
