"""`manage.py worker_host add|key|list|release|remove NAME`: the farm's worker hosts;
`worker_host grants ROLE HOST...`: the SQL for their own database role."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from django.core.exceptions import ValidationError
from django.core.management.base import BaseCommand, CommandError
from django.db.models import ProtectedError

from printers.dbclock import learn_offset
from printers.heartbeat import HostRefused, release
from printers.host_role import BadRoleName, grant_statements
from printers.hosts import WorkerHost

if TYPE_CHECKING:
    from argparse import ArgumentParser


class Command(BaseCommand):
    help = (
        "Add a worker host (its key is shown once), issue it a new key, list the "
        "hosts with their heartbeat, release the name of one whose computer is gone "
        "for good, or remove one that drives no printer."
    )

    def add_arguments(self, parser: ArgumentParser) -> None:
        actions = parser.add_subparsers(dest="action", required=True)
        add = actions.add_parser("add", help="a new worker host; prints its key")
        add.add_argument("name")
        add.add_argument("--description", default="")
        key = actions.add_parser("key", help="a new key (the old one stops working)")
        key.add_argument("name")
        actions.add_parser("list", help="the hosts, their printers and heartbeat")
        release = actions.add_parser(
            "release",
            help="its last computer is gone for good: the name may start elsewhere",
        )
        release.add_argument("name")
        remove = actions.add_parser("remove", help="remove a host with no printers")
        remove.add_argument("name")
        grants = actions.add_parser(
            "grants",
            help="print the SQL that gives a worker host's own database role what "
            "it needs and no more, its writes kept to the rows of the hosts named "
            "(printers/host_role.py)",
        )
        grants.add_argument("role")
        grants.add_argument("hosts", nargs="+", metavar="host")

    def handle(self, *args: Any, **options: Any) -> None:
        action = options["action"]
        if action == "list":
            self._list()
            return
        if action == "grants":
            try:
                statements = grant_statements(options["role"], options["hosts"])
            except BadRoleName as error:
                raise CommandError(str(error)) from None
            known = set(WorkerHost.objects.values_list("name", flat=True))
            if unknown := sorted(set(options["hosts"]) - known):
                raise CommandError(
                    f"no worker host named {', '.join(unknown)} (known: "
                    f"{', '.join(sorted(known)) or 'none'}): add it first"
                )
            self.stdout.write("\n".join(statements))
            return
        name = options["name"]
        if action == "add":
            host = WorkerHost(name=name, description=options["description"])
            try:
                host.full_clean()
            except ValidationError as error:
                raise CommandError(_messages(error)) from None
            host.save()
            self._show_key(host, host.issue_key())
            return
        host = WorkerHost.objects.filter(name=name).first()
        if host is None:
            known = ", ".join(WorkerHost.objects.values_list("name", flat=True))
            raise CommandError(
                f"no worker host named {name!r} (known: {known or 'none'})"
            )
        if action == "key":
            self._show_key(host, host.issue_key())
        elif action == "release":
            try:
                release(host)
            except HostRefused as error:
                raise CommandError(str(error)) from None
            self.stdout.write(
                f"released worker host {name}: its runhost may start on any computer"
            )
        elif action == "remove":
            try:
                host.delete()
            except ProtectedError:
                slugs = ", ".join(host.printer_set.values_list("slug", flat=True))
                raise CommandError(
                    f"worker host {name} still drives {slugs}: move those printers "
                    "to another host first"
                ) from None
            self.stdout.write(f"removed worker host {name}")

    def _show_key(self, host: WorkerHost, key: str) -> None:
        self.stdout.write(f"worker host {host.name}: key (shown once): {key}")
        self.stdout.write(
            "on that host set PRINTHOST_HOST_KEY to it, PRINTHOST_CONTROL_URL to the "
            f"control plane's address, and run: manage.py runhost --no-web "
            f"--worker-host {host.name}"
        )

    def _list(self) -> None:
        learn_offset()  # heartbeats are stamped by the database's clock
        for host in WorkerHost.objects.prefetch_related("printer_set"):
            age = host.heartbeat_age()
            seen = "never seen" if age is None else f"seen {age:.0f} s ago"
            state = "online" if host.online else "offline"
            slugs = ", ".join(p.slug for p in host.printer_set.all()) or "no printers"
            self.stdout.write(
                f"{host.name}: {state}, {seen}, {host.hostname or '-'} "
                f"{host.version or ''}: {slugs}"
            )


def _messages(error: ValidationError) -> str:
    return "; ".join(
        f"{field}: {' '.join(messages)}"
        for field, messages in error.message_dict.items()
    )
