"""Redis goes away mid-print for the whole farm (channel layer and Celery's broker,
every process through one TCP proxy the test cuts, then restores).

The prints go on untouched and complete; websocket clients of printers on three
hosts, connected to the control plane all along, end with every line of their
printer's log, in order, once (catching up by last id)."""

from __future__ import annotations

import time

import pytest

from tests.conftest import wait_for
from tests.farmrig import checks
from tests.farmrig.clients import Watcher
from tests.farmrig.crowd import Crowd

pytestmark = [pytest.mark.slow, pytest.mark.services]

CUT_SECONDS = 4.0


def test_prints_go_on_and_clients_catch_up_with_redis_away(make_farm):
    farm = make_farm(proxy_redis=True)
    farm.start()
    watched = [p.slug for p in farm.printers[:3]]  # one on each host
    assert len({p.host for p in farm.printers[:3]}) == 3
    url = f"ws://127.0.0.1:{farm.control.port}/ws/printers"
    crowd = Crowd([Watcher(f"{url}/{slug}/", slug) for slug in watched], farm.operator)
    crowd.start()
    try:
        wait_for(crowd.connected, 30, "the clients to connect")
        farm.upload()
        printers = [p.slug for p in farm.printers]
        farm.mid_print(printers, 0.2, timeout=60)
        executed = lambda: sum(len(checks.executed(farm, s)) for s in printers)
        at_cut = executed()
        farm.redis_proxy.cut()
        cut_at = time.monotonic()
        wait_for(lambda: executed() > at_cut + 1000, 30, "the prints to go on")
        wait_for(lambda: time.monotonic() - cut_at >= CUT_SECONDS, 30, "the cut")
        farm.redis_proxy.restore()
        farm.run_to_end(timeout=120)
        checks.response_log_whole(farm)
        finals = dict(farm.query(
            "SELECT p.slug, MAX(r.seq) FROM printers_responseline r "
            "JOIN printers_printer p ON p.id = r.printer_id GROUP BY p.slug"))  # fmt: skip
        crowd.finish(finals, timeout=60)
    finally:
        crowd.stop()

    checks.jobs_ran_once(farm)
    checks.records_match(farm)
    for watcher in crowd.watchers:
        final = finals[watcher.slug]
        expected = farm.query(
            "SELECT seq, text FROM printers_responseline WHERE printer_id = %s "
            "AND seq > %s AND seq <= %s ORDER BY seq",
            farm.ids[watcher.slug], watcher.start, final,
        )  # fmt: skip
        got = [line for line in watcher.lines if line[0] <= final]
        assert len(got) > 1000, f"{watcher.slug}: the client saw no print"
        assert got == [tuple(row) for row in expected], (
            f"{watcher.slug}: a client missed, repeated or reordered a line"
        )
    # The consumers waited Redis out: nobody was dropped.
    assert [w.reconnects for w in crowd.watchers] == [0, 0, 0]
    logs = farm.logs()
    assert "Exception inside application" not in logs
