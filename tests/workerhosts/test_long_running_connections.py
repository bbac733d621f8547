"""Long-running loops keep their database connection; a PostgreSQL that went away
fails a connection in seconds."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from tests.conftest import ROOT

_TURNS = """
import django; django.setup()
from django.db import close_old_connections, connection
from printers.models import Printer
from printhost.longrunning import close_failed_connections
seen = []  # kept alive, so that no two connections share an id
for _ in range(3):
    list(Printer.objects.all())
    seen.append(connection.connection)
    {close}()  # what every turn of a loop does
print(len({{id(c) for c in seen}}))
"""


@pytest.mark.parametrize(("keep", "connections"), [(False, 3), (True, 1)])
def test_a_long_running_process_keeps_its_connection_between_turns(
    tmp_path, keep, connections
):
    from tests.hosts import Host

    host = Host(tmp_path)
    host.migrate()
    code = _TURNS.format(
        close="close_failed_connections" if keep else "close_old_connections"
    )
    env = {**host.env, "DJANGO_SETTINGS_MODULE": "printhost.settings"}
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
        text=True, check=True,
    ).stdout  # fmt: skip
    assert int(out) == connections


def test_postgresql_connections_give_up_after_a_few_seconds():
    code = (
        "import json, django; django.setup(); from django.conf import settings; "
        "print(json.dumps(settings.DATABASES['default']['OPTIONS']))"
    )
    env = {
        **os.environ,
        "DJANGO_SETTINGS_MODULE": "printhost.settings",
        "DATABASE_URL": "postgres://postgres@127.0.0.1:5432/printhost",
    }
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
        text=True, check=True,
    ).stdout  # fmt: skip
    assert json.loads(out)["connect_timeout"] == 3
