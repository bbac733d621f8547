"""Admin actions need the permission their effect needs, not only the page's view
permission: staff who may look at jobs, printers and keys cannot delete, stop,
requeue or revoke with them."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from django.contrib.auth import get_user_model
from django.contrib.auth.models import Permission
from django.test import Client

from jobs.models import Job
from printers.models import Printer, QueuedCommand
from printhost.access import issue_key
from printhost.models import ApiKey

pytestmark = pytest.mark.django_db


def staff_with(*codenames: str) -> Client:
    user = get_user_model().objects.create_user(
        f"staff-{len(codenames)}", password="x", is_staff=True
    )
    user.user_permissions.add(*Permission.objects.filter(codename__in=codenames))
    client = Client()
    client.force_login(user)
    return client


@pytest.mark.parametrize(
    "changing",
    [(), ("change_job", "change_printer", "change_apikey")],
    ids=["view only", "change, no delete"],
)
def test_actions_need_the_change_or_delete_permission(
    make_printer: Callable[..., Printer],
    make_job: Callable[..., Job],
    changing: tuple[str, ...],
) -> None:
    printer = make_printer(state="idle")
    job = make_job(printer, "G28\n")
    Job.objects.filter(pk=job.pk).update(state="failed")
    owner = get_user_model().objects.create_superuser("root", password="x")
    issue_key(owner, "slicer")
    client = staff_with("view_job", "view_printer", "view_apikey", *changing)

    def act(path: str, action: str, pk: int) -> None:
        client.post(path, {"action": action, "_selected_action": [pk]})

    act("/admin/jobs/job/", "delete_with_files", job.pk)
    act("/admin/jobs/job/", "requeue", job.pk)
    act("/admin/printers/printer/", "stop_now", printer.pk)
    act("/admin/printhost/apikey/", "revoke", ApiKey.objects.get().pk)

    allowed = bool(changing)
    assert Job.objects.filter(pk=job.pk).exists(), "deleting needs delete_job"
    assert (Job.objects.get(pk=job.pk).state == "queued") is allowed
    assert QueuedCommand.objects.filter(text="M112").exists() is allowed
    assert (ApiKey.objects.get().revoked_at is not None) is allowed
