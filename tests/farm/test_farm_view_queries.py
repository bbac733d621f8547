"""`GET /printer/farm` costs the same queries however many printers, hosts and farm
jobs there are: the key, the roles, the waiting jobs, the printers (read once for
the queue's "would go to" and for the list), the latest given ones, the hosts."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import pytest
from django.contrib.auth import get_user_model
from django.test import Client
from django.utils import timezone

from jobs.farm.dispatch import Dispatcher
from jobs.farm.models import FarmJob
from printers.hosts import WorkerHost
from printhost.access import issue_key
from printhost.models import PrinterRole, Role
from tests.farm.conftest import box_gcode

if TYPE_CHECKING:
    from collections.abc import Callable

    from printers.models import Printer

pytestmark = pytest.mark.django_db

FARM_QUERIES = 6


def test_the_farm_view_costs_the_same_queries_for_two_printers_or_ten(
    farm_printer: Callable[..., Printer],
    to_farm: Callable[..., FarmJob],
    django_assert_num_queries: Callable[..., Any],
) -> None:
    user = get_user_model().objects.create_user("viewer")
    PrinterRole.objects.create(user=user, role=Role.VIEWER, printer=None)
    key = issue_key(user, "test")[1]

    def grow(first: int, last: int) -> None:
        """Printers *first*..*last* on a host of their own, each given a job, one
        more job waiting for a printer and one cancelled."""
        host = WorkerHost.objects.create(name=f"rack-{first}", seen_at=timezone.now())
        for n in range(first, last):
            farm_printer(f"mk3-{n:02d}", worker_host=host)
            to_farm(box_gcode(60, 40, 10), name=f"given-{n}.gcode")
        Dispatcher().run_pass()
        to_farm(box_gcode(60, 40, 10), name=f"waiting-{first}.gcode")
        cancelled = to_farm(box_gcode(60, 40, 10), name=f"cancelled-{first}.gcode")
        FarmJob.objects.filter(pk=cancelled.pk).update(state=FarmJob.State.CANCELLED)

    def farm() -> dict[str, Any]:
        response = Client().get("/printer/farm", HTTP_X_API_KEY=key)
        assert response.status_code == 200, response.content
        return response.json()["data"]

    grow(0, 2)
    farm()  # stamps the key's first use (then once a minute)
    with django_assert_num_queries(FARM_QUERIES):
        two = farm()
    grow(2, 10)
    with django_assert_num_queries(FARM_QUERIES):
        ten = farm()

    assert (len(two["printers"]), len(ten["printers"])) == (2, 10)
    assert len(ten["hosts"]) == 2
    states = [job["state"] for job in ten["jobs"]]
    assert states.count("waiting") == 2 and states.count("assigned") == 10
    assert {job["printer"] for job in ten["jobs"] if job["state"] == "assigned"} == {
        f"mk3-{n:02d}" for n in range(10)
    }
