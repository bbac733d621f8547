"""The printer lease (one worker per printer) and the response log's ids (its retention:
tests/upkeep/test_upkeep_response_log.py)."""

from __future__ import annotations

from datetime import timedelta

import pytest
from django.utils import timezone

from printers.models import Printer, ResponseLine
from printers.protocol.events import LineKind
from printers.worker.lease import Lease, LeaseLost
from printers.worker.responselog import ResponseLog

pytestmark = pytest.mark.django_db


def test_second_worker_cannot_claim_a_printer_that_is_held(make_printer):
    printer = make_printer()
    first, second = Lease(printer.pk, "a:1:x", 10), Lease(printer.pk, "b:2:y", 10)

    assert first.claim()
    assert not second.claim()
    assert second.holder() == "a:1:x"


def test_expired_lease_can_be_taken_over(make_printer):
    printer = make_printer()
    first, second = Lease(printer.pk, "a:1:x", 10), Lease(printer.pk, "b:2:y", 10)
    assert first.claim()
    Printer.objects.filter(pk=printer.pk).update(
        lease_expires_at=timezone.now() - timedelta(seconds=1)
    )

    assert second.claim()
    with pytest.raises(LeaseLost, match="b:2:y"):
        first.renew_if_due(now=100.0)


def test_released_lease_is_free_again(make_printer):
    printer = make_printer()
    first, second = Lease(printer.pk, "a:1:x", 10), Lease(printer.pk, "b:2:y", 10)
    assert first.claim()
    first.release()
    assert second.claim()


def test_log_ids_keep_growing_across_workers(make_printer):
    printer = make_printer()
    log = ResponseLog(printer.pk)
    for i in range(5):
        log.add(f"line {i}", LineKind.RESPONSE)
    log.flush()

    again = ResponseLog(printer.pk)
    assert again.add("next", LineKind.ACK) == 6


def test_log_lines_are_not_stored_once_the_lease_was_taken_over(make_printer):
    printer = make_printer()
    lease = Lease(printer.pk, "a:1:x", 10)
    lease.take(now=0.0)
    log = ResponseLog(printer.pk, lease=lease)
    log.add("before", LineKind.RESPONSE)
    log.flush()
    Printer.objects.filter(pk=printer.pk).update(lease_owner="b:2:y")
    log.add("after", LineKind.RESPONSE)

    with pytest.raises(LeaseLost, match="b:2:y"):
        log.flush()
    assert list(ResponseLine.objects.values_list("text", flat=True)) == ["before"]
    with pytest.raises(LeaseLost):
        lease.renew_if_due(now=100.0)
