"""The farm's figures in Prometheus' format, read from the database at scrape time.

`FarmCollector` is a prometheus-client collector: each scrape reads the printers
(with their worker hosts), their running jobs, the job counts and the worker hosts
in four queries whatever the number of printers, and turns the rows into metric
families. Nothing is kept between scrapes, so every daphne process (and each worker
host's `serve_metrics`) answers the same.

Series (labels `printer` = slug, `host` = worker host name, `_control` for the
printers the control plane's own runhost drives; a worker host cannot be called
that, names start with a letter or digit):

    printhost_printer_info{printer,host,firmware,profile,material,colour}   1
    printhost_printer_state{printer,host,state}      1 for the current state, 0 else
    printhost_printer_link_use_ratio                 bits sent / what the baud carries
    printhost_printer_lines_per_second
    printhost_printer_resends_per_1000_lines         since the connect
    printhost_printer_timeouts_per_1000_lines        since the connect
    printhost_printer_ack_round_trip_seconds         mean ack round trip
    printhost_printer_link_stats_age_seconds         since the worker last saved them
    printhost_printer_{lines_sent,lines_acked,resends,timeouts,bytes_sent,
        bytes_received}_total                        counters since the connect
    printhost_printer_worker_cpu_seconds_total       the worker process's CPU time
    printhost_printer_temperature_celsius{printer,host,heater}
    printhost_printer_temperature_target_celsius{printer,host,heater}
    printhost_job_progress_ratio, printhost_job_lines_acked, printhost_job_lines,
    printhost_job_id                                 the printer's running job
    printhost_jobs{state}                            queued, printing, paused jobs
    printhost_host_up{host}, printhost_host_heartbeat_age_seconds{host},
    printhost_host_load_average{host,minutes}, printhost_host_cpus{host},
    printhost_host_memory_free_bytes{host}, printhost_host_disk_free_bytes{host},
    printhost_host_printers{host}, printhost_host_printers_running{host},
    printhost_host_worker_restarts{host}, printhost_host_info{host,version,hostname}

Link figures are the worker's (`Printer.link_stats`); the rates (lines per second,
link use) of stats older than `STALE_SECONDS` are 0: no worker is sending. A value
that is missing or not a finite number is left out, never a failed scrape.
"""

from __future__ import annotations

from datetime import datetime
from typing import TYPE_CHECKING, Any

from django.db.models import Count
from django.utils import timezone
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

from jobs.models import Job
from printers.dbclock import shared_time
from printers.hosts import WorkerHost, number
from printers.models import Printer

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator

    from prometheus_client import Metric

#: The `host` label of printers without a worker host (the control plane runs them).
CONTROL_HOST = "_control"
#: Link stats older than this (s) mean the worker is not writing: rates read 0.
STALE_SECONDS = 30.0
#: Job states counted in printhost_jobs.
ACTIVE_JOB_STATES = (Job.State.QUEUED, Job.State.PRINTING, Job.State.PAUSED)

PRINTER = ["printer", "host"]
#: What the job series read of a running job.
JOB_FIELDS = ("id", "printer_id", "state", "lines_acked", "line_count", "bytes_acked",
              "size_bytes")  # fmt: skip

#: (series, link_stats key, scale, help): gauges read from link_stats.
LINK_GAUGES = (
    ("printhost_printer_link_use_ratio", "link_use", 1.0,
     "Share of the serial link's capacity in use (bits sent over what the baud rate carries)"),
    ("printhost_printer_lines_per_second", "lines_per_s", 1.0,
     "Lines acknowledged per second over the last few seconds"),
    ("printhost_printer_ack_round_trip_seconds", "rtt_ms", 0.001,
     "Mean time from sending a line to its acknowledgement"),
)  # fmt: skip
#: Rates that drop to 0 when the stats are stale.
RATE_KEYS = {"link_use", "lines_per_s"}
#: (series without _total, link_stats key, help): counters since the connect.
LINK_COUNTERS = (
    ("printhost_printer_lines_sent", "lines_sent", "Lines sent since the connect"),
    ("printhost_printer_lines_acked", "lines_acked", "Lines acknowledged since the connect"),
    ("printhost_printer_resends", "resends", "Resend requests since the connect"),
    ("printhost_printer_timeouts", "timeouts", "Acknowledgement timeouts since the connect"),
    ("printhost_printer_bytes_sent", "bytes_sent", "Bytes written to the port since the connect"),
    ("printhost_printer_bytes_received", "bytes_received", "Bytes read from the port since the connect"),
)  # fmt: skip


def epoch(text: object) -> float | None:
    """An ISO time from a JSON field as seconds since the epoch, or None."""
    if not isinstance(text, str) or not text:
        return None
    try:
        moment = datetime.fromisoformat(text)
    except ValueError:
        return None
    if timezone.is_naive(moment):
        moment = timezone.make_aware(moment, timezone.utc)
    return moment.timestamp()


def host_label(printer: Printer) -> str:
    return printer.worker_host.name if printer.worker_host_id else CONTROL_HOST


class FarmCollector:
    """Every printer's, job's and worker host's figures; or one worker host's only."""

    def __init__(self, host: str | None = None) -> None:
        #: A worker host's name: its printers and its own row only.
        self.host = host

    def collect(self) -> Iterator[Metric]:
        printers = Printer.objects.select_related("worker_host").order_by("slug")
        hosts = WorkerHost.objects.order_by("name")
        if self.host is not None:
            printers = printers.filter(worker_host__name=self.host)
            hosts = hosts.filter(name=self.host)
        printers = list(printers)
        now = shared_time()
        yield from printer_families(printers, now)
        yield from job_families(printers, running_jobs(printers))
        if self.host is None:
            yield job_counts()
        yield from host_families(list(hosts), now)


def printer_families(printers: Iterable[Printer], now: float) -> Iterator[Metric]:
    """State, link figures and temperatures of *printers*."""
    info = GaugeMetricFamily(
        "printhost_printer_info",
        "A printer, its firmware and what is loaded (always 1)",
        labels=[*PRINTER, "firmware", "profile", "material", "colour"],
    )
    state = GaugeMetricFamily(
        "printhost_printer_state",
        "1 for the printer's current state, 0 for the others",
        labels=[*PRINTER, "state"],
    )
    for printer in printers:
        labels = [printer.slug, host_label(printer)]
        info.add_metric(
            [*labels, printer.firmware, printer.profile, printer.material,
             printer.colour], 1.0,
        )  # fmt: skip
        for choice in Printer.State.values:
            state.add_metric([*labels, choice], float(printer.state == choice))
    yield info
    yield state
    yield from link_families(printers, now)
    yield from temperature_families(printers)


def link_families(printers: Iterable[Printer], now: float) -> Iterator[Metric]:
    """The worker's link figures: rates, per-1,000-line ratios and raw counters."""
    gauges = {
        key: (GaugeMetricFamily(name, text, labels=PRINTER), scale)
        for name, key, scale, text in LINK_GAUGES
    }
    counters = {
        key: CounterMetricFamily(name, text, labels=PRINTER)
        for name, key, text in LINK_COUNTERS
    }
    cpu = CounterMetricFamily(
        "printhost_printer_worker_cpu_seconds",
        "CPU time of the printer's worker process",
        labels=PRINTER,
    )
    age = GaugeMetricFamily(
        "printhost_printer_link_stats_age_seconds",
        "Seconds since the worker last saved the link figures",
        labels=PRINTER,
    )
    per_1000 = {
        key: GaugeMetricFamily(
            f"printhost_printer_{key}_per_1000_lines",
            f"{key.capitalize()} per 1,000 lines sent since the connect",
            labels=PRINTER,
        )
        for key in ("resends", "timeouts")
    }
    for printer in printers:
        stats = printer.link_stats if isinstance(printer.link_stats, dict) else {}
        if not stats:
            continue
        labels = [printer.slug, host_label(printer)]
        at = epoch(stats.get("at"))
        stale = at is None or now - at > STALE_SECONDS
        if at is not None:
            age.add_metric(labels, max(0.0, now - at))
        for key, (family, scale) in gauges.items():
            value = number(stats.get(key))
            if value is not None:
                family.add_metric(
                    labels, 0.0 if stale and key in RATE_KEYS else value * scale
                )
        created = epoch(stats.get("connected_at"))
        for key, family in counters.items():
            value = number(stats.get(key))
            if value is not None:
                family.add_metric(labels, value, created=created)
        sent = number(stats.get("lines_sent"))
        for key, family in per_1000.items():
            value = number(stats.get(key))
            if value is not None and sent:
                family.add_metric(labels, 1000.0 * value / sent)
        seconds = number(stats.get("cpu_s"))
        if seconds is not None:
            cpu.add_metric(labels, seconds)
    yield from (family for family, _ in gauges.values())
    yield from per_1000.values()
    yield from counters.values()
    yield cpu
    yield age


def temperature_families(printers: Iterable[Printer]) -> Iterator[Metric]:
    """Each heater's reading and target, as the worker last saved them."""
    current = GaugeMetricFamily(
        "printhost_printer_temperature_celsius",
        "A heater's last reported temperature",
        labels=[*PRINTER, "heater"],
    )
    target = GaugeMetricFamily(
        "printhost_printer_temperature_target_celsius",
        "A heater's target temperature (0: off)",
        labels=[*PRINTER, "heater"],
    )
    for printer in printers:
        readings = printer.temperatures
        if not isinstance(readings, dict):
            continue
        for heater, reading in sorted(readings.items()):
            if not isinstance(reading, dict):
                continue
            labels = [printer.slug, host_label(printer), str(heater)]
            for family, key in ((current, "current"), (target, "target")):
                value = number(reading.get(key))
                if value is not None:
                    family.add_metric(labels, value)
    yield current
    yield target


def running_jobs(printers: list[Printer]) -> dict[int, Job]:
    """Each printer's printing or paused job (the newest, should there be two)."""
    jobs = (
        Job.objects.filter(
            printer_id__in=[p.pk for p in printers],
            state__in=[Job.State.PRINTING, Job.State.PAUSED],
        )
        .only(*JOB_FIELDS)
        .order_by("id")
    )
    return {job.printer_id: job for job in jobs}


def job_families(printers: Iterable[Printer], jobs: dict[int, Job]) -> Iterator[Metric]:
    """The running job of each printer that has one."""
    families = {
        "progress": GaugeMetricFamily(
            "printhost_job_progress_ratio",
            "Share of the running job's file acknowledged by the firmware (0..1)",
            labels=PRINTER,
        ),
        "lines_acked": GaugeMetricFamily(
            "printhost_job_lines_acked",
            "Lines of the running job acknowledged by the firmware",
            labels=PRINTER,
        ),
        "line_count": GaugeMetricFamily(
            "printhost_job_lines", "Lines of the running job's file", labels=PRINTER
        ),
        "id": GaugeMetricFamily(
            "printhost_job_id", "Id of the printer's running job", labels=PRINTER
        ),
    }
    for printer in printers:
        job = jobs.get(printer.pk)
        if job is None:
            continue
        labels = [printer.slug, host_label(printer)]
        for key, family in families.items():
            family.add_metric(labels, float(getattr(job, key)))
    yield from families.values()


def job_counts() -> Metric:
    """Jobs waiting and running, farm-wide (one grouped count)."""
    family = GaugeMetricFamily(
        "printhost_jobs", "Jobs queued, printing and paused", labels=["state"]
    )
    rows = (
        Job.objects.filter(state__in=ACTIVE_JOB_STATES)
        .values("state")
        .order_by()
        .annotate(n=Count("id"))
    )
    counts = {row["state"]: row["n"] for row in rows}
    for state in ACTIVE_JOB_STATES:
        family.add_metric([str(state)], float(counts.get(state, 0)))
    return family


def host_families(hosts: Iterable[WorkerHost], now: float) -> Iterator[Metric]:
    """Each worker host's heartbeat and the load it reported with it."""
    yield from HostFamilies(hosts, now).families()


class HostFamilies:
    """The worker host series, filled from the hosts' rows."""

    def __init__(self, hosts: Iterable[WorkerHost], now: float) -> None:
        self.hosts = list(hosts)
        self.now = now

    def families(self) -> Iterator[Metric]:
        gauge = self._gauge
        up = gauge("up", "1 while the host's heartbeat is fresh")
        age = gauge("heartbeat_age_seconds", "Seconds since the host's last heartbeat")
        load = gauge("load_average", "The host's load average", extra=["minutes"])
        cpus = gauge("cpus", "CPUs of the host")
        memory = gauge("memory_free_bytes", "Memory available on the host")
        disk = gauge("disk_free_bytes", "Free space in the host's data directory")
        clock = gauge("clock_offset_seconds", "The database's clock minus the host's")
        count = gauge("printers", "Printers the host runs workers for")
        running = gauge("printers_running", "Workers of the host that are running")
        restarts = gauge("worker_restarts", "Worker restarts since the host started")
        info = gauge(
            "info", "A host's version (always 1)", extra=["version", "hostname"]
        )
        for host in self.hosts:
            name = [host.name]
            up.add_metric(name, float(host.online))
            info.add_metric([*name, host.version, host.hostname], 1.0)
            heard = host.heartbeat_age()
            if heard is not None:
                age.add_metric(name, heard)
            self._load(host, load, cpus, memory, disk, clock)
            workers = host.printers if isinstance(host.printers, dict) else {}
            states = [w for w in workers.values() if isinstance(w, dict)]
            count.add_metric(name, float(len(workers)))
            running.add_metric(name, float(sum(bool(w.get("running")) for w in states)))
            total = sum(number(w.get("restarts")) or 0.0 for w in states)
            restarts.add_metric(name, total)
        yield from (up, age, load, cpus, memory, disk, clock)
        yield from (count, running, restarts, info)

    @staticmethod
    def _gauge(
        name: str, text: str, extra: list[str] | None = None
    ) -> GaugeMetricFamily:
        return GaugeMetricFamily(
            f"printhost_host_{name}", text, labels=["host", *(extra or [])]
        )

    @staticmethod
    def _load(host: WorkerHost, *families: GaugeMetricFamily) -> None:
        load_family, cpus, memory, disk, clock = families
        load: dict[str, Any] = host.load if isinstance(host.load, dict) else {}
        averages = load.get("loadavg")
        if isinstance(averages, list) and len(averages) == 3:
            for minutes, value in zip(("1", "5", "15"), averages, strict=True):
                if (figure := number(value)) is not None:
                    load_family.add_metric([host.name, minutes], figure)
        for family, key, scale in (
            (cpus, "cpus", 1), (memory, "memory_free_mb", 1024**2),
            (disk, "disk_free_mb", 1024**2), (clock, "clock_offset_s", 1),
        ):  # fmt: skip
            if (figure := number(load.get(key))) is not None:
                family.add_metric([host.name], figure * scale)
