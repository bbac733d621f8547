"""A real slice printed on the Marlin simulator under runhost, with the remaining time
the job reports sampled as it prints: the ETA end-to-end test
(tests/analysis/test_eta_end_to_end.py) and `make bench`'s ETA section
(bench/eta.py) both run it.

The simulator times its moves as a firmware does (printers/simulator/_kinematics.py)
times `--time-scale`; runhost's Celery worker analyses the file before the print
starts. The heater waits are taken out of the file (M190/M109 become M140/M104):
the simulator's heaters are not the analyser's heater model, and heating is
reported apart from motion.

Times are the server's: each sample is the job's `elapsed` with the `eta` and
`time_progress` of the same answer, and the print took the job's `elapsed` once it
completed, so neither the sampler's pauses nor HTTP round trips enter the figures.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import httpx

from tests.conftest import wait_for
from tests.hosts import Host

if TYPE_CHECKING:
    from pathlib import Path

#: Shares of the print (time progress, %) at which the remaining time is checked.
CHECKS = (25.0, 50.0, 75.0)
#: Allowed error of the reported remaining time, as a share of the true one.
TOLERANCE = 0.05
#: Seconds between two samples of the job.
SAMPLE_EVERY = 0.25


def without_heater_waits(text: str) -> str:
    """*text* with its heater waits as plain settings: M190 → M140, M109 → M104."""
    text = re.sub(r"^M190 ", "M140 ", text, flags=re.M)
    return re.sub(r"^M109 ", "M104 ", text, flags=re.M)


@dataclass(frozen=True, slots=True)
class Sample:
    """One answer of `/printer/job?a=list` while the job printed."""

    #: Seconds since the job started (the job's `elapsed`).
    elapsed: float
    #: Time progress by the analysis, %.
    progress: float
    #: The remaining time it reported, seconds.
    remaining: float
    #: Commands the firmware had acknowledged (the estimate's line).
    line: int


@dataclass(frozen=True, slots=True)
class Check:
    """The remaining time reported at a share of the print against the real one."""

    progress: float
    said: float
    real: float

    @property
    def error(self) -> float:
        """(said - real) / real."""
        return (self.said - self.real) / self.real


@dataclass(frozen=True, slots=True)
class EtaRun:
    """What a print reported while it ran, and how long it really took."""

    samples: list[Sample]
    #: The job's elapsed seconds when it completed.
    took: float
    #: The file's analysed motion seconds (the model's time for the print).
    motion_seconds: float

    def checks(self, shares: tuple[float, ...] = CHECKS) -> list[Check]:
        """At each share, the first sample at or past it against the time the print
        then really took."""
        out = []
        for share in shares:
            sample = next(s for s in self.samples if s.progress >= share)
            out.append(
                Check(sample.progress, sample.remaining, self.took - sample.elapsed)
            )
        return out

    def table(self, shares: tuple[float, ...] = CHECKS) -> str:
        """The checks as a Markdown table."""
        rows = [
            "| progress (time) | remaining said | remaining really | error |",
            "|---|---|---|---|",
        ]
        for check in self.checks(shares):
            rows.append(
                f"| {check.progress:.1f} % | {check.said:.1f} s | {check.real:.1f} s "
                f"| {100 * check.error:+.1f} % |"
            )
        return "\n".join(rows)


def print_and_sample(
    folder: Path, source: Path, time_scale: float, *, timeout: float = 3600.0
) -> EtaRun:
    """Print *source* (heater waits out) on a simulated Marlin whose motion takes
    *time_scale* of its firmware time, sampling the job every SAMPLE_EVERY seconds;
    fail if it does not complete within *timeout* seconds of starting."""
    host = Host(folder)
    host.migrate()
    host.add_simulated_printer("mk3", sim_args=f"--time-scale {time_scale}")
    key = host.add_user("op", role="operator")
    sliced = folder / "slice.gcode"
    sliced.write_text(without_heater_waits(source.read_text()))
    samples: list[Sample] = []
    with (
        host.running(celery=True),
        httpx.Client(
            base_url=host.url, headers={"X-Api-Key": key}, timeout=30
        ) as client,
    ):
        wait_for(
            lambda: host.query("SELECT state FROM printers_printer")[0][0] == "idle",
            60, "the printer to connect",
        )  # fmt: skip
        # Stored, analysed, then started: the print starts with its analysis ready.
        stored = client.post(
            "/printer/job/mk3",
            data={"a": "upload", "autostart": "0"},
            files={"filename": ("slice.gcode", sliced.read_bytes())},
        )
        stored.raise_for_status()
        job_id = stored.json()["data"]["id"]
        wait_for(
            lambda: host.query("SELECT state FROM jobs_fileanalysis") == [("done",)],
            120, "runhost's Celery worker to analyse the file",
        )  # fmt: skip
        client.post(
            "/printer/job/mk3", data={"a": "start", "id": job_id}
        ).raise_for_status()
        ended: dict = {}

        def sample() -> bool:
            jobs = client.get("/printer/job/mk3?a=list").json()["data"]
            job = next(j for j in jobs if j["id"] == job_id)
            if job["state"] not in ("queued", "printing"):
                ended.update(job)
                return True
            said = (job["elapsed"], job["time_progress"], job["eta"])
            if None not in said:
                samples.append(Sample(*said, line=job["lines_acked"]))
            return False

        # Four samples a second (the pause paces the sampling).
        wait_for(
            sample, timeout, "the print to end",
            step=lambda: time.sleep(SAMPLE_EVERY),
        )  # fmt: skip
        assert ended["state"] == "completed", (ended["message"], host.log_tail())
        motion = ended["analysis"]["motion_seconds"] if ended["analysis"] else 0.0
    assert samples, "no remaining time was reported while printing"
    return EtaRun(samples, ended["elapsed"], motion)
