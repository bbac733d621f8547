"""/metrics over the test client: per-printer, job and worker host series, parsed."""

from __future__ import annotations

from datetime import timedelta

import pytest
from django.db import connection
from django.test.utils import CaptureQueriesContext
from django.utils import timezone

from printers.models import Printer
from printhost.metrics import CONTROL_HOST, STALE_SECONDS
from printhost.metrics_view import scrape as exposition
from tests.ops.conftest import samples, value

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("no_latency_history")]


def test_each_printer_reports_its_state_one_hot(farm, scrape):
    found = scrape()
    for printer, state in (("mk4", "printing"), ("voron", "idle")):
        for choice in Printer.State.values:
            labels = {"printer": printer, "host": "rack1", "state": choice}
            want = 1.0 if choice == state else 0.0
            assert value(found, "printhost_printer_state", **labels) == want


def test_link_figures_come_from_the_workers_link_stats(farm, scrape):
    found = scrape()
    mk4 = {"printer": "mk4", "host": "rack1"}
    assert value(found, "printhost_printer_link_use_ratio", **mk4) == 0.85
    assert value(found, "printhost_printer_lines_per_second", **mk4) == 180.0
    assert value(found, "printhost_printer_ack_round_trip_seconds", **mk4) == 0.0125
    assert value(found, "printhost_printer_resends_per_1000_lines", **mk4) == 1.5
    assert value(found, "printhost_printer_timeouts_per_1000_lines", **mk4) == 0.2
    assert value(found, "printhost_printer_lines_sent_total", **mk4) == 20000
    assert value(found, "printhost_printer_resends_total", **mk4) == 30
    assert value(found, "printhost_printer_bytes_received_total", **mk4) == 90000
    assert value(found, "printhost_printer_worker_cpu_seconds_total", **mk4) == 42.0
    # A counter since the connect carries the connect time as its start.
    connected = farm.busy.link_stats["connected_at"]
    created = value(found, "printhost_printer_lines_sent_created", **mk4)
    assert created == pytest.approx(
        timezone.datetime.fromisoformat(connected).timestamp()
    )
    assert value(found, "printhost_printer_link_stats_age_seconds", **mk4) < 60
    # A printer whose worker never wrote link stats has no link series.
    assert ("printhost_printer_link_use_ratio",
            frozenset({"printer": "voron", "host": "rack1"}.items())) not in found  # fmt: skip


def test_temperatures_and_targets_per_heater(farm, scrape):
    found = scrape()
    hotend = {"printer": "mk4", "host": "rack1", "heater": "T0"}
    bed = {**hotend, "heater": "B"}
    assert value(found, "printhost_printer_temperature_celsius", **hotend) == 214.5
    assert value(found, "printhost_printer_temperature_target_celsius", **hotend) == 215
    assert value(found, "printhost_printer_temperature_celsius", **bed) == 60.2
    assert value(found, "printhost_printer_temperature_target_celsius", **bed) == 60


def test_the_running_job_reports_progress_and_lines(farm, scrape):
    found = scrape()
    mk4 = {"printer": "mk4", "host": "rack1"}
    assert value(found, "printhost_job_progress_ratio", **mk4) == pytest.approx(
        farm.job.progress
    )
    assert 0.2 < value(found, "printhost_job_progress_ratio", **mk4) < 0.3
    assert value(found, "printhost_job_lines_acked", **mk4) == 25
    assert value(found, "printhost_job_lines", **mk4) == farm.job.line_count
    assert value(found, "printhost_job_id", **mk4) == farm.job.pk
    assert value(found, "printhost_jobs", state="printing") == 1
    assert value(found, "printhost_jobs", state="queued") == 0
    idle = frozenset({"printer": "voron", "host": "rack1"}.items())
    assert ("printhost_job_progress_ratio", idle) not in found


def test_worker_hosts_report_heartbeat_age_and_load(farm, scrape):
    found = scrape()
    assert 3.5 < value(found, "printhost_host_heartbeat_age_seconds", host="rack1") < 60
    assert value(found, "printhost_host_up", host="rack1") == 1
    assert (
        value(found, "printhost_host_load_average", host="rack1", minutes="5") == 0.25
    )
    assert value(found, "printhost_host_cpus", host="rack1") == 4
    assert value(found, "printhost_host_memory_free_bytes", host="rack1") == 512 * 2**20
    assert value(found, "printhost_host_clock_offset_seconds", host="rack1") == -3.5
    assert value(found, "printhost_host_printers", host="rack1") == 2
    assert value(found, "printhost_host_printers_running", host="rack1") == 1
    assert value(found, "printhost_host_worker_restarts", host="rack1") == 3
    info = {"host": "rack1", "version": "0.1.0", "hostname": "pi-rack1"}
    assert value(found, "printhost_host_info", **info) == 1


def test_a_silent_host_is_down_and_its_age_grows(farm, scrape):
    farm.rack.seen_at = timezone.now() - timedelta(minutes=10)
    farm.rack.save()
    found = scrape()
    assert value(found, "printhost_host_up", host="rack1") == 0
    assert value(found, "printhost_host_heartbeat_age_seconds", host="rack1") >= 600


def test_stale_link_stats_read_as_no_traffic(farm, scrape):
    old = timezone.now() - timedelta(seconds=STALE_SECONDS + 5)
    Printer.objects.filter(pk=farm.busy.pk).update(
        link_stats={**farm.busy.link_stats, "at": old.isoformat()}
    )
    found = scrape()
    mk4 = {"printer": "mk4", "host": "rack1"}
    assert value(found, "printhost_printer_lines_per_second", **mk4) == 0
    assert value(found, "printhost_printer_link_use_ratio", **mk4) == 0
    assert value(found, "printhost_printer_lines_sent_total", **mk4) == 20000
    assert (
        value(found, "printhost_printer_link_stats_age_seconds", **mk4) >= STALE_SECONDS
    )


def test_junk_in_the_json_fields_is_left_out_not_a_failed_scrape(farm, scrape):
    Printer.objects.filter(pk=farm.busy.pk).update(
        link_stats={"at": "yesterday", "lines_sent": "many", "resends": None,
                    "rtt_ms": [12], "link_use": True, "timeouts": 3},
        temperatures={"T0": "hot", "B": {"current": "x", "target": 50}},
    )  # fmt: skip
    farm.rack.load = {"loadavg": "high"}
    farm.rack.save()
    found = scrape()
    mk4 = {"printer": "mk4", "host": "rack1"}
    assert value(found, "printhost_printer_timeouts_total", **mk4) == 3
    for name in ("printhost_printer_lines_sent_total", "printhost_printer_link_use_ratio",
                 "printhost_printer_timeouts_per_1000_lines"):  # fmt: skip
        assert (name, frozenset(mk4.items())) not in found
    bed = {**mk4, "heater": "B"}
    assert value(found, "printhost_printer_temperature_target_celsius", **bed) == 50
    assert not [k for k in found if k[0] == "printhost_host_load_average"]
    assert value(found, "printhost_host_up", host="rack1") == 1


def test_printers_without_a_worker_host_belong_to_the_control_plane(
    make_printer, scrape
):
    make_printer(slug="solo", state=Printer.State.OFFLINE)
    found = scrape()
    labels = {"printer": "solo", "host": CONTROL_HOST, "state": "offline"}
    assert value(found, "printhost_printer_state", **labels) == 1


def test_a_scrape_reads_a_few_queries_whatever_the_number_of_printers(
    farm, make_printer
):
    def queries() -> int:
        with CaptureQueriesContext(connection) as captured:
            exposition()
        return len(captured)

    few = queries()
    for n in range(20):
        make_printer(
            slug=f"extra{n}", worker_host=farm.rack, link_stats={"lines_sent": n}
        )
    assert queries() == few <= 4


def test_a_worker_hosts_scrape_holds_its_printers_and_its_row_only(farm, make_printer):
    make_printer(slug="solo", state=Printer.State.IDLE)
    body, _ = exposition(host="rack1")
    found = samples(body.decode())
    printers = {
        dict(labels).get("printer")
        for name, labels in found
        if name == "printhost_printer_state"
    }
    assert printers == {"mk4", "voron"}
    hosts = {
        dict(labels)["host"]
        for name, labels in found
        if name.startswith("printhost_host_")
    }
    assert hosts == {"rack1"}
    assert not [
        k for k in found if k[0].startswith(("printhost_http_", "printhost_celery_"))
    ]
