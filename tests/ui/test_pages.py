"""The browser pages: who sees which page, and what a page shows before its script runs."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import pytest
from django.contrib.auth import get_user_model

from printhost.models import PrinterRole, Role

if TYPE_CHECKING:
    from collections.abc import Callable

    from django.test import Client

    from printers.models import Printer


def user_with(role: int | None, printer: Printer | None = None, name: str = "u") -> Any:
    user = get_user_model().objects.create_user(name, password=name)
    if role is not None:
        PrinterRole.objects.create(user=user, printer=printer, role=role)
    return user


@pytest.fixture
def shop(make_printer: Callable[..., Printer], make_job: Callable[..., Any]) -> Any:
    """Two printers, a job on the first, a viewer of the second only."""
    first = make_printer(name="Prusa", slug="prusa", state="idle")
    second = make_printer(name="Mill", slug="mill", firmware="grbl")
    job = make_job(first, "G28\nG1 X10\n", name="cube.gcode")
    return {"first": first, "second": second, "job": job}


def pages(shop: Any) -> list[str]:
    return ["/", "/printers/prusa/", f"/jobs/{shop['job'].pk}/", "/account/"]


def test_every_page_answers_an_operator(client: Client, shop: Any) -> None:
    client.force_login(user_with(Role.OPERATOR))
    for url in pages(shop):
        response = client.get(url)
        assert response.status_code == 200, url
        assert b'data-test="user-menu"' in response.content
        assert b'data-test="error"' in response.content


def test_anonymous_is_sent_to_the_login_page(client: Client, shop: Any) -> None:
    for url in pages(shop):
        response = client.get(url)
        assert response.status_code == 302, url
        assert response["Location"].startswith(f"/accounts/login/?next={url}")


def test_login_page_has_the_fields_the_contract_names(client: Client, db: None) -> None:
    body = client.get("/accounts/login/").content.decode()
    assert 'id="id_username"' in body and 'id="id_password"' in body
    user_with(None, name="ann")
    failed = client.post("/accounts/login/", {"username": "ann", "password": "no"})
    assert 'role="alert"' in failed.content.decode()


def test_viewer_of_another_printer_gets_the_styled_403(
    client: Client, shop: Any
) -> None:
    client.force_login(user_with(Role.VIEWER, shop["second"]))
    for url in ("/printers/prusa/", f"/jobs/{shop['job'].pk}/"):
        response = client.get(url)
        assert response.status_code == 403, url
        assert b"viewer role needed on printer &#x27;prusa&#x27;" in response.content
        assert b'data-test="user-menu"' in response.content


def test_viewer_sees_the_printer_read_only(client: Client, shop: Any) -> None:
    client.force_login(user_with(Role.VIEWER, shop["first"]))
    body = client.get("/printers/prusa/").content.decode()
    assert 'data-test="terminal"' in body and 'data-test="temp-chart"' in body
    assert 'data-test="queue-job"' in body
    for hidden in ("controls", "command", "send", "upload", "connect", "pause"):
        assert f'data-test="{hidden}"' not in body, hidden
    assert 'data-test="estop" class="estop sticky" disabled' in body


def test_operator_sees_controls_for_the_firmware(client: Client, shop: Any) -> None:
    client.force_login(user_with(Role.OPERATOR))
    marlin = client.get("/printers/prusa/").content.decode()
    assert 'data-test="motors-off"' in marlin and 'data-test="set-hotend"' in marlin
    assert 'data-test="unlock"' not in marlin
    grbl = client.get("/printers/mill/").content.decode()
    assert 'data-test="unlock"' in grbl and 'data-test="feed-hold"' in grbl
    assert 'data-test="set-hotend"' not in grbl
    assert 'data-test="port"' not in marlin.split('data-test="connection"')[0]


def test_dashboard_lists_only_viewable_printers(client: Client, shop: Any) -> None:
    client.force_login(user_with(Role.VIEWER, shop["second"]))
    body = client.get("/").content.decode()
    assert 'data-printer="mill"' in body
    assert 'data-printer="prusa"' not in body


def test_dashboard_card_shows_state_temperatures_and_bed_clear(
    client: Client, shop: Any
) -> None:
    printer = shop["first"]
    printer.state = "waitstart"
    printer.temperatures = {"T0": {"current": 205.2, "target": 210}}
    printer.save()
    client.force_login(user_with(Role.OPERATOR))
    body = client.get("/").content.decode()
    card = body.split('data-printer="prusa"')[1].split("</article>")[0]
    assert "waiting for the bed to be cleared" in card
    assert "T0 205/210 °C" in card
    assert 'data-test="bed-clear" class="primary" >' in card  # not hidden
    assert 'data-test="estop"' in card


def test_printer_page_renders_the_log_with_ids_and_kinds(
    client: Client, shop: Any
) -> None:
    from django.utils import timezone

    from printers.models import ResponseLine

    for seq, kind in ((1, 1), (2, 2), (3, 8)):
        ResponseLine.objects.create(
            printer=shop["first"],
            seq=seq,
            time=timezone.now(),
            text=f"l{seq}",
            kind=kind,
        )
    client.force_login(user_with(Role.OPERATOR))
    body = client.get("/printers/prusa/").content.decode()
    assert 'data-test="line" data-id="3" data-type="8">l3<' in body
    assert 'data-last="3"' in body


def test_job_page_lists_runs_of_the_same_file(client: Client, shop: Any) -> None:
    from jobs.services import reprint

    again = reprint(shop["job"])
    client.force_login(user_with(Role.OPERATOR))
    body = client.get(f"/jobs/{again.pk}/").content.decode()
    assert shop["job"].sha256 in body
    runs = body.split('data-test="runs"')[1]
    assert f'data-job="{again.pk}"' in runs and f'data-job="{shop["job"].pk}"' in runs


def test_account_page_lists_own_keys_only(client: Client, shop: Any) -> None:
    from printhost.access import issue_key

    me = user_with(Role.OPERATOR)
    other = user_with(Role.OPERATOR, name="other")
    mine, _ = issue_key(me, "slicer")
    theirs, _ = issue_key(other, "theirs")
    client.force_login(me)
    body = client.get("/account/").content.decode()
    assert mine.prefix in body and theirs.prefix not in body
    assert 'data-test="key-revoke"' in body


def test_unknown_printer_is_404(client: Client, shop: Any) -> None:
    client.force_login(user_with(Role.OPERATOR))
    assert client.get("/printers/nope/").status_code == 404


def test_dashboard_shows_the_heartbeat_of_the_hosts_its_printers_run_on(
    client: Client, shop: Any
) -> None:
    from datetime import timedelta

    from django.utils import timezone

    from printers.hosts import WorkerHost

    shelf = WorkerHost.objects.create(
        name="shelf-1", version="0.1.0", seen_at=timezone.now(),
        load={"loadavg": [0.42, 0.3, 0.2], "cpus": 4, "clock_offset_s": 1.9},
    )  # fmt: skip
    WorkerHost.objects.create(
        name="shelf-2",
        seen_at=timezone.now() - timedelta(minutes=2),
        load={"clock_offset_s": -75.4},
    )
    WorkerHost.objects.create(name="elsewhere", seen_at=timezone.now())
    shop["first"].worker_host = shelf
    shop["first"].save()
    shop["second"].worker_host = WorkerHost.objects.get(name="shelf-2")
    shop["second"].save()
    client.force_login(user_with(Role.VIEWER, shop["first"]))
    body = client.get("/").content.decode()
    hosts = body.split('data-test="hosts"')[1].split("</section>")[0]
    one = hosts.split('data-host="shelf-1"')[1].split("</li>")[0]
    assert ">online<" in one and "1 printer · printhost 0.1.0" in one
    assert "load 0.42 on 4 CPUs" in one
    assert "its clock" not in one  # within CLOCK_WARN_SECONDS
    assert "shelf-2" not in hosts and "elsewhere" not in hosts  # not theirs to see
    client.force_login(user_with(Role.VIEWER, shop["second"], name="v2"))
    body = client.get("/").content.decode()
    two = body.split('data-host="shelf-2"')[1].split("</li>")[0]
    assert ">offline<" in two and "heartbeat 120 s ago" in two
    assert "its clock is 75 s ahead of the database&#x27;s" in two


def test_dashboard_without_worker_hosts_shows_no_host_panel(
    client: Client, shop: Any
) -> None:
    client.force_login(user_with(Role.OPERATOR))
    assert 'data-test="hosts"' not in client.get("/").content.decode()
