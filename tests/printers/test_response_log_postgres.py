"""The response log on real PostgreSQL, where a batch goes in by COPY: every line
comes back as it was logged (text of any kind, order, ids, kinds, one time per
batch), a worker whose lease was taken stores nothing, and a connection that
drops mid-batch loses no line and stores none twice, whether the batch went in
or not."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING
from urllib.parse import urlparse

import pytest

from tests.hosts import Host, postgres_url
from tests.netfault import TcpProxy

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


#: A worker's log that meets a dropped connection in its first batch, then goes on.
BLIP = """
import json, time
from printers.models import Printer, ResponseLine
from printers.protocol.events import LineKind
from printers.worker.lease import DatabaseAway, Lease
from printers.worker.responselog import ResponseLog
printer = Printer.objects.create(name="P", slug="p", port="/nonexistent")
lease = Lease(printer.pk, "a:1:x", 30)
lease.take(time.monotonic())
lease.keep_while_away = True
log = ResponseLog(printer.pk, lease=lease)
for n in range(100):
    log.add(f"line {n}", LineKind.RESPONSE)
tries = []
give_up = time.monotonic() + 30
while not tries or tries[-1] == "away":
    try:
        log.flush()
        tries.append("stored")
    except DatabaseAway:
        tries.append("away")
        assert time.monotonic() < give_up, tries
        time.sleep(0.1)  # the lease tries the database again after 0.5 s
log.add("after", LineKind.RESPONSE)
log.flush()
rows = list(ResponseLine.objects.order_by("seq").values_list("seq", "text"))
print(json.dumps({"rows": rows, "tries": tries}))
"""


@pytest.mark.parametrize(
    ("marker", "after_reply"),
    [(b"COPY ", False), (b"COMMIT", True)],
    ids=["dropped-before-the-copy-reached-the-server", "commit-reply-lost"],
)
def test_a_batch_cut_off_by_a_dropped_connection_is_stored_once(
    tmp_path: Path, marker: bytes, after_reply: bool
):
    """Before the COPY reached the server the batch is not in; after the server
    committed it, with its answer lost, it is: the worker cannot tell which, and
    must neither lose it nor store it twice (ids are unique: twice would refuse
    every batch from then on)."""
    direct = postgres_url()
    Host(tmp_path, direct).migrate()
    proxy = TcpProxy(("127.0.0.1", 5432))
    try:
        database = urlparse(direct).path
        host = Host(tmp_path, proxy.url("postgresql", database, user="postgres"))
        proxy.cut_at(marker, after_reply=after_reply)
        out = json.loads(host.shell(BLIP).splitlines()[-1])
        assert proxy.blipped.is_set()
    finally:
        proxy.close()

    assert out["tries"][0] == "away" and out["tries"][-1] == "stored"
    expected = [[n + 1, f"line {n}"] for n in range(100)] + [[101, "after"]]
    assert out["rows"] == expected
