"""Worker hosts: one runhost per name, heartbeats, which printers each runhost
drives, and the `worker_host` command's answers to bad input."""

from __future__ import annotations

import socket
import subprocess
import sys

import pytest
from django.core.management import call_command
from django.core.management.base import CommandError

from printers.heartbeat import HostRefused, HostRegistration, boot_id
from printers.hosts import WorkerHost
from printers.supervisor import Supervisor


@pytest.fixture
def shelf(db: None) -> WorkerHost:
    return WorkerHost.objects.create(name="shelf-1")


def _dead_pid() -> int:
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


def test_claiming_writes_who_runs_the_host_and_heartbeats_keep_it(shelf):
    registration = HostRegistration("shelf-1")
    host = registration.claim()
    assert host.instance == registration.instance
    assert host.hostname == socket.gethostname() and host.version
    assert host.online and host.load["cpus"] >= 1
    assert registration.beat({"p1": {"pid": 7, "running": True, "restarts": 0}})
    assert WorkerHost.objects.get(pk=shelf.pk).printers["p1"]["pid"] == 7


def test_an_unknown_or_disabled_host_is_refused_with_what_to_do(shelf):
    with pytest.raises(HostRefused, match=r"no worker host named 'shelf-9'.*shelf-1"):
        HostRegistration("shelf-9").claim()
    WorkerHost.objects.filter(pk=shelf.pk).update(enabled=False)
    with pytest.raises(HostRefused, match="disabled"):
        HostRegistration("shelf-1").claim()


def test_a_second_runhost_with_the_same_name_is_refused_while_the_first_lives(shelf):
    first = HostRegistration("shelf-1")
    first.claim()  # this test's own process: alive
    with pytest.raises(HostRefused, match="already running"):
        HostRegistration("shelf-1").claim()
    elsewhere = HostRegistration("shelf-1", instance="other-computer:123:abcdef")
    WorkerHost.objects.filter(pk=shelf.pk).update(instance=elsewhere.instance)
    with pytest.raises(HostRefused, match="it runs on other-computer"):
        HostRegistration("shelf-1").claim()


@pytest.mark.parametrize("boot", [boot_id(), None], ids=["boot id", "older row"])
def test_a_killed_runhost_on_this_computer_is_taken_over_at_once(shelf, boot):
    here = [socket.gethostname(), str(_dead_pid())]
    dead = ":".join([*here, boot, "abcdef"] if boot is not None else [*here, "abc"])
    old = HostRegistration("shelf-1", instance=dead)
    old.claim()
    new = HostRegistration("shelf-1")
    assert new.claim().instance == new.instance
    assert not old.beat({})  # the old one, were it alive, learns it lost the name


def _held_by(shelf: WorkerHost, instance: str, *, minutes_ago: float) -> None:
    from datetime import timedelta

    from django.utils import timezone

    WorkerHost.objects.filter(pk=shelf.pk).update(
        instance=instance,
        hostname=instance.partition(":")[0],
        seen_at=timezone.now() - timedelta(minutes=minutes_ago),
    )


def test_a_copy_of_this_computer_with_a_fresh_heartbeat_is_not_taken_over(shelf):
    """The same hostname and a pid that is free here prove nothing on another
    computer cloned from the same system image (another boot id)."""
    clone = f"{socket.gethostname()}:{_dead_pid()}:0ther800t:abcdef"
    _held_by(shelf, clone, minutes_ago=0)
    with pytest.raises(HostRefused, match=r"already running.*named .* too"):
        HostRegistration("shelf-1").claim()
    _held_by(shelf, clone, minutes_ago=5)  # this computer before a restart
    assert HostRegistration("shelf-1").claim().hostname == socket.gethostname()


def test_a_host_gone_quiet_on_another_computer_is_taken_over_only_once_released(
    shelf,
):
    """Cut off from the database, it may still be printing: its printers' ports are
    not this computer's. An operator says it is gone for good."""
    _held_by(shelf, "other-computer:1:b00t1d00:abcdef", minutes_ago=5)
    with pytest.raises(HostRefused, match=r"last ran on other-computer.*release"):
        HostRegistration("shelf-1").claim()

    call_command("worker_host", "release", "shelf-1")
    assert HostRegistration("shelf-1").claim().hostname == socket.gethostname()


def test_only_a_superuser_releases_a_host_in_the_admin(shelf):
    from django.contrib.auth import get_user_model
    from django.contrib.auth.models import Permission
    from django.test import Client

    _held_by(shelf, "other-computer:1:b00t1d00:abcdef", minutes_ago=5)
    staff = get_user_model().objects.create_user("staff", password="x", is_staff=True)
    staff.user_permissions.add(*Permission.objects.filter(codename__endswith="host"))
    root = get_user_model().objects.create_superuser("root", password="x")
    asked = {"action": "release_hosts", "_selected_action": [shelf.pk]}
    for user, released in ((staff, False), (root, True)):
        client = Client()
        client.force_login(user)
        answer = client.post("/admin/printers/workerhost/", asked, follow=True)
        shown = [str(m) for m in answer.context["messages"]]
        instance = WorkerHost.objects.get(pk=shelf.pk).instance
        assert (instance == "") is released, shown
    assert shown == ["released worker host shelf-1"]


def test_a_running_host_cannot_be_released(shelf):
    HostRegistration("shelf-1", instance="other-computer:1:b00t1d00:abc").claim()
    with pytest.raises(CommandError, match=r"is running on .*stop it instead"):
        call_command("worker_host", "release", "shelf-1")
    assert WorkerHost.objects.get(pk=shelf.pk).instance.startswith("other-computer")


def test_leaving_lets_the_next_runhost_start_at_once(shelf):
    first = HostRegistration("shelf-1")
    first.claim()
    first.leave()
    assert not WorkerHost.objects.get(pk=shelf.pk).online
    HostRegistration("shelf-1").claim()


def test_each_runhost_drives_only_its_own_printers(shelf, make_printer):
    other = WorkerHost.objects.create(name="shelf-2")
    local = make_printer(slug="local")
    mine = make_printer(slug="mine", worker_host=shelf)
    make_printer(slug="theirs", worker_host=other)
    make_printer(slug="off", worker_host=shelf, enabled=False)

    def workers(**options) -> list[str]:
        supervisor = Supervisor(bind="127.0.0.1", port=1, celery=False, **options)
        return sorted(n for n in supervisor.wanted() if n.startswith("worker:"))

    assert workers() == [f"worker:{local.slug}"]
    assert workers(workers=False) == []
    registration = HostRegistration("shelf-1")
    assert workers(worker_host=registration, serve_web=False) == [f"worker:{mine.slug}"]


def test_a_worker_host_fetches_files_only_when_it_has_a_control_plane(
    shelf, make_printer, settings
):
    make_printer(slug="mine", worker_host=shelf)
    supervisor = Supervisor(
        bind="127.0.0.1", port=1, serve_web=False, celery=False,
        worker_host=HostRegistration("shelf-1"),
    )  # fmt: skip
    assert "fetcher" not in supervisor.wanted()  # a shared disk: nothing to fetch
    settings.PRINTHOST_CONTROL_URL = "http://control.example:8000"
    assert supervisor.wanted()["fetcher"][-2:] == ["--worker-host", "shelf-1"]
    assert "daphne" not in supervisor.wanted()


def test_the_supervisor_keeps_running_while_the_database_is_away(shelf, monkeypatch):
    from django.db import OperationalError

    supervisor = Supervisor(
        bind="127.0.0.1", port=1, serve_web=False, celery=False,
        worker_host=HostRegistration("shelf-1"),
    )  # fmt: skip
    supervisor.worker_host.claim()

    def away() -> None:
        raise OperationalError("server closed the connection unexpectedly")

    monkeypatch.setattr(supervisor, "wanted", away)
    monkeypatch.setattr(supervisor.worker_host, "beat", lambda printers: away())
    supervisor.step(0.0)
    assert not supervisor.shutdown and supervisor._database_away


def test_a_host_whose_name_was_taken_stops_its_supervisor(shelf):
    registration = HostRegistration("shelf-1")
    registration.claim()
    WorkerHost.objects.filter(pk=shelf.pk).update(instance="elsewhere:1:x")
    supervisor = Supervisor(
        bind="127.0.0.1", port=1, serve_web=False, celery=False,
        worker_host=registration,
    )  # fmt: skip
    supervisor.step(0.0)
    assert supervisor.shutdown


def test_worker_host_add_shows_a_key_that_fetches_and_refuses_bad_names(db, capsys):
    call_command("worker_host", "add", "rack-a", "--description", "left rack")
    out = capsys.readouterr().out
    key = out.split("key (shown once): ")[1].split()[0]
    host = WorkerHost.objects.get(name="rack-a")
    assert host.key_matches(key) and host.description == "left rack"
    with pytest.raises(CommandError, match="already exists"):
        call_command("worker_host", "add", "rack-a")
    with pytest.raises(CommandError, match="name"):
        call_command("worker_host", "add", "Rack A!")
    with pytest.raises(CommandError, match="no worker host named 'rack-b'"):
        call_command("worker_host", "key", "rack-b")


def test_a_host_that_drives_printers_cannot_be_removed(shelf, make_printer, capsys):
    make_printer(slug="mine", worker_host=shelf)
    with pytest.raises(CommandError, match="still drives mine"):
        call_command("worker_host", "remove", "shelf-1")
    call_command("worker_host", "list")
    assert "shelf-1: offline, never seen" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--no-web", "--worker-host", "nobody"], "no worker host named 'nobody'"),
        (["--worker-host", "nobody"], "a worker host serves no web UI"),
        (["--no-web", "--no-workers", "--worker-host", "x"], "drop --no-workers"),
    ],
)
def test_runhost_refuses_a_worker_host_it_cannot_be(tmp_path, args, words):
    from tests.hosts import Host

    host = Host(tmp_path)
    host.migrate()
    result = host.manage("runhost", *args, check=False)
    assert result.returncode == 1
    assert words in result.stderr


def test_a_worker_host_serves_its_own_metrics_only_when_asked(shelf):
    def children(**options) -> dict[str, list[str]]:
        return Supervisor(
            bind="127.0.0.1", port=1, serve_web=False, celery=False,
            worker_host=HostRegistration("shelf-1"), **options,
        ).wanted()  # fmt: skip

    assert "metrics" not in children()
    argv = children(metrics_port=9108, metrics_bind="0.0.0.0")["metrics"]
    assert argv[-7:] == [
        "serve_metrics", "--worker-host", "shelf-1", "--bind", "0.0.0.0",
        "--port", "9108",
    ]  # fmt: skip


def test_the_control_plane_runs_the_dispatcher_once_the_farm_is_used(
    shelf, make_printer, make_job
):
    from jobs.farm.models import FarmJob

    control = Supervisor(bind="127.0.0.1", port=1, celery=False, workers=False)
    assert "dispatcher" not in control.wanted()
    job = make_job(make_printer(), "G28\n")
    FarmJob.objects.create(name="part.gcode", file=job.file, sha256=job.sha256)
    assert control.wanted()["dispatcher"][-1] == "run_dispatcher"
    host = Supervisor(
        bind="127.0.0.1", port=1, serve_web=False, celery=False,
        worker_host=HostRegistration("shelf-1"),
    )  # fmt: skip
    assert "dispatcher" not in host.wanted()


def test_behind_a_proxy_daphne_takes_the_clients_address_from_its_headers(db, settings):
    plain = Supervisor(bind="127.0.0.1", port=1, celery=False).wanted()["daphne"]
    assert "--proxy-headers" not in plain
    settings.SECURE_PROXY_SSL_HEADER = ("HTTP_X_FORWARDED_PROTO", "https")
    proxied = Supervisor(bind="127.0.0.1", port=1, celery=False).wanted()["daphne"]
    assert proxied[-2:] == ["--proxy-headers", "printhost.asgi:application"]


def test_heartbeats_are_written_and_judged_by_the_database_clock(shelf, monkeypatch):
    """A board minutes off (no battery-backed clock, NTP not there yet) neither
    looks stale while it runs nor lets an operator release it then."""
    from datetime import timedelta

    from django.utils import timezone

    from printers.dbclock import database_now

    right = timezone.now
    off = lambda minutes: lambda: right() + timedelta(minutes=minutes)
    monkeypatch.setattr(timezone, "now", off(-10))  # the host's clock is behind
    host = HostRegistration("shelf-1", instance="other-computer:1:b00t1d00:abc")
    host.claim()
    assert host.beat({})
    seen = WorkerHost.objects.get(pk=shelf.pk).seen_at
    assert abs((seen - database_now()).total_seconds()) < 5

    monkeypatch.setattr(timezone, "now", off(+10))  # the operator's clock is ahead
    with pytest.raises(CommandError, match="is running on"):
        call_command("worker_host", "release", "shelf-1")
    with pytest.raises(HostRefused, match="already running"):
        HostRegistration("shelf-1").claim()
