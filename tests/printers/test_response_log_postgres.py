"""The response log on real PostgreSQL, where a batch goes in by COPY: every line
comes back as it was logged (text of any kind, order, ids, kinds, one time per
batch), and a worker whose lease was taken stores nothing."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import pytest

from tests.hosts import Host, postgres_url

if TYPE_CHECKING:
    from pathlib import Path

pytestmark = pytest.mark.services

#: Text COPY's own format would take apart if it were written unescaped.
AWKWARD = [
    "ok N12 P15 B3",
    "tab\there, backslash \\ and \\N, a quote ' \" and a pipe |",
    'echo:Unknown command: "M9999"',
    "\ufffd\ufffd start",
    "",
    "x" * 3000,
]

LOG = """
import json
from printers.models import Printer, ResponseLine
from printers.protocol.events import LineKind
from printers.worker.lease import Lease, LeaseLost
from printers.worker.responselog import ResponseLog
texts = json.loads({texts!r})
printer = Printer.objects.create(name="P", slug="p", port="/nonexistent")
lease = Lease(printer.pk, "a:1:x", 10)
lease.take(now=0.0)
log = ResponseLog(printer.pk, lease=lease)
for text in texts:
    log.add(text, LineKind.RESPONSE)
log.add("sent", LineKind.COMMAND)
log.flush()
Printer.objects.filter(pk=printer.pk).update(lease_owner="b:2:y")
log.add("after the lease went", LineKind.RESPONSE)
try:
    log.flush()
    refused = False
except LeaseLost:
    refused = True
rows = list(ResponseLine.objects.order_by("seq").values_list("seq", "text", "kind"))
times = set(ResponseLine.objects.values_list("time", flat=True))
print(json.dumps({{"rows": rows, "times": len(times), "refused": refused}}))
"""


def test_a_batch_copied_into_postgresql_comes_back_line_for_line(tmp_path: Path):
    host = Host(tmp_path, postgres_url())
    host.migrate()

    printed = host.shell(LOG.format(texts=json.dumps(AWKWARD)))
    out = json.loads(printed.splitlines()[-1])

    expected = [[i + 1, text, 4] for i, text in enumerate(AWKWARD)]
    expected.append([len(AWKWARD) + 1, "sent", 1])
    assert out["rows"] == expected
    assert out["times"] == 1  # logged within a millisecond: one time for all
    assert out["refused"], "a worker that lost its lease stored its lines"
