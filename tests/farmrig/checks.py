"""What a farm run must show, read from the database and the simulators' records.

Each check returns nothing and raises AssertionError with what went wrong:
- `jobs_ran_once`: every farm job became exactly one printer job, which completed,
  with one completed history entry; nothing waits, nothing is queued.
- `matching_printers`: each ran on a printer that meets its requirements (the
  harness's own reading, `fleet.meets`, against the analysed bounding box).
- `records_match`: each simulator ran exactly its jobs' files' commands, one job
  after another in the order they started (the worker's own commands left out).
- `response_log_whole`: per printer, the response log's ids run 1..n with no gap
  and every command of its jobs was logged as sent, in order.
"""

from __future__ import annotations

import contextlib
import json
import re
from collections import Counter, defaultdict
from typing import TYPE_CHECKING

from printers.sample_gcode import commands_of
from tests.conftest import HOST_COMMANDS, wait_for
from tests.farmrig.fleet import meets

if TYPE_CHECKING:
    from tests.farmrig.rig import Farm

FRAMED = re.compile(r"^N\d+ (.*)\*\d+$")


def job_commands(text: str) -> list[str]:
    """The commands of a job's file the firmware runs, as the checks compare them."""
    return [c for c in commands_of(text) if not c.startswith(HOST_COMMANDS)]


def executed(farm: Farm, slug: str) -> list[str]:
    """What *slug*'s simulator ran of jobs (its worker's own commands left out)."""
    ran = farm.sims[slug].executed()[farm.record_offsets.get(slug, 0) :]
    return [c for c in ran if c and not c.startswith(HOST_COMMANDS)]


def runs(farm: Farm) -> list[tuple[int, int, str, str, str]]:
    """(farm job, job, printer slug, job state, farm state) of every farm job."""
    return farm.query(
        "SELECT f.id, j.id, p.slug, j.state, f.state FROM jobs_farmjob f "
        "LEFT JOIN jobs_job j ON j.id = f.job_id "
        "LEFT JOIN printers_printer p ON p.id = j.printer_id ORDER BY f.id"
    )


def jobs_ran_once(farm: Farm, *, allowed: dict[int, str] | None = None) -> None:
    """Every upload ran once and completed (*allowed*: job id -> another final state
    a test caused, e.g. interrupted)."""
    allowed = allowed or {}
    rows = runs(farm)
    assert sorted(r[0] for r in rows) == sorted(farm.uploaded), "uploads missing"
    assert [r for r in rows if r[4] != "assigned"] == [], "a farm job still waits"
    job_ids = [r[1] for r in rows]
    assert len(set(job_ids)) == len(job_ids), "one printer job for two farm jobs"
    everything = [
        (j, s)
        for j, s in farm.query("SELECT id, state FROM jobs_job ORDER BY id")
        if j not in farm.other_jobs
    ]
    assert sorted(job_ids) == [j for j, _ in everything], "a job not from the farm"
    wrong = {j: s for j, s in everything if s != allowed.get(j, "completed")}
    assert wrong == {}, f"jobs that did not end as they should: {wrong}"
    history = [
        (j, o)
        for j, o in farm.query("SELECT job_number, outcome FROM jobs_historyentry")
        if j not in farm.other_jobs
    ]
    counts = Counter(j for j, _ in history)
    assert all(counts[j] == 1 for j in job_ids), f"history entries: {counts}"
    outcomes = {j: o for j, o in history}
    assert outcomes == {j: allowed.get(j, "completed") for j in job_ids}


def matching_printers(farm: Farm) -> None:
    """Each farm job ran on a printer that meets what it asked."""
    specs = {p.slug: p for p in farm.printers}
    rows = farm.query(
        "SELECT f.id, p.slug, a.summary FROM jobs_farmjob f "
        "JOIN printers_printer p ON p.id = f.printer_id "
        "JOIN jobs_fileanalysis a ON a.id = f.analysis_id"
    )
    assert len(rows) == len(farm.uploaded)
    for farm_job, slug, summary in rows:
        job = farm.uploaded[farm_job]
        data = summary if isinstance(summary, dict) else json.loads(summary)
        box = data.get("bbox")
        assert meets(job.asks, specs[slug], box), (
            f"{job.name} ({job.asks}, box {box}) went to {slug}, which does not meet it"
        )


def jobs_of(farm: Farm, slug: str) -> list[tuple[int, str, int, int]]:
    """(job id, state, lines acked, farm job id) of *slug*'s jobs in start order."""
    return farm.query(
        "SELECT j.id, j.state, j.lines_acked, f.id FROM jobs_job j "
        "JOIN printers_printer p ON p.id = j.printer_id "
        "JOIN jobs_farmjob f ON f.job_id = j.id "
        "WHERE p.slug = %s ORDER BY j.started_at, j.id",
        slug,
    )


def records_match(
    farm: Farm, *, cut_short: dict[int, tuple[int, int]] | None = None
) -> None:
    """Each simulator's record is its jobs' files' commands, one after another.

    *cut_short*: job id -> (fewest, most) commands of an interrupted run the
    firmware may have run (what it acknowledged, and what was on the wire).
    """
    cut_short = cut_short or {}
    for spec in farm.printers:
        ran = executed(farm, spec.slug)
        at = 0
        for job_id, _state, _acked, farm_job in jobs_of(farm, spec.slug):
            commands = job_commands(farm.uploaded[farm_job].text())
            if job_id in cut_short:
                fewest, most = cut_short[job_id]
                done = _prefix(ran[at:], commands)
                assert fewest <= done <= most, (
                    f"{spec.slug}: job {job_id} ran {done} commands, not "
                    f"{fewest} to {most}"
                )
                at += done
                continue
            got = ran[at : at + len(commands)]
            assert got == commands, (
                f"{spec.slug}: job {job_id} ran {_difference(got, commands)}"
            )
            at += len(commands)
        assert ran[at:] == [], f"{spec.slug} ran {len(ran) - at} commands of no job"


def _prefix(ran: list[str], commands: list[str]) -> int:
    n = 0
    while n < min(len(ran), len(commands)) and ran[n] == commands[n]:
        n += 1
    return n


def _difference(got: list[str], want: list[str]) -> str:
    n = _prefix(got, want)
    return (
        f"{len(got)} of {len(want)} commands; first difference at {n}: "
        f"{got[n : n + 2]} instead of {want[n : n + 2]}"
    )


def response_log_whole(farm: Farm, within: float = 10.0) -> None:
    """Per printer: ids 1..n, each once; every job command logged as sent, in order.

    A worker writes its log every 0.25 s, after the job's row: the log may trail
    the job's end by a batch, so the check waits for it (at most *within* s)."""

    def whole() -> bool:
        try:
            _log_is_whole(farm)
        except AssertionError:
            return False
        return True

    with contextlib.suppress(AssertionError):
        wait_for(whole, within, "the response log to settle")
    _log_is_whole(farm)


def _log_is_whole(farm: Farm) -> None:
    ids = farm.ids
    by_printer: dict[int, list[int]] = defaultdict(list)
    for printer, seq in farm.query(
        "SELECT printer_id, seq FROM printers_responseline ORDER BY printer_id, seq"
    ):
        by_printer[printer].append(seq)
    for slug, pk in ids.items():
        seqs = by_printer[pk]
        assert seqs == list(range(1, len(seqs) + 1)), f"{slug}: ids with gaps"
        sent = [
            FRAMED.sub(r"\1", text)
            for (text,) in farm.query(
                "SELECT text FROM printers_responseline WHERE printer_id = %s "
                "AND kind = 1 ORDER BY seq",
                pk,
            )
        ]
        sent = [c for c in sent if not c.startswith(HOST_COMMANDS)]
        want = [
            c
            for job_id, *_rest, farm_job in jobs_of(farm, slug)
            for c in job_commands(farm.uploaded[farm_job].text())
        ]
        assert sent == want, (
            f"{slug}: the log's sent commands {_difference(sent, want)}"
        )
