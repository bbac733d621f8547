"""Upkeep: each printer's response log is trimmed to its `response_log_limit` by beat,
and the printer's worker no longer deletes lines in its loop."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest
from django.utils import timezone

from printers.models import ResponseLine
from printers.protocol.events import LineKind
from printers.upkeep import trim_response_logs
from printers.worker.responselog import ResponseLog

if TYPE_CHECKING:
    from collections.abc import Callable

    from printers.models import Printer

pytestmark = pytest.mark.django_db


def log_lines(printer: Printer, count: int) -> None:
    now = timezone.now()
    ResponseLine.objects.bulk_create(
        ResponseLine(printer=printer, seq=seq, time=now, text=f"line {seq}", kind=2)
        for seq in range(1, count + 1)
    )


def kept(printer: Printer) -> list[int]:
    return list(
        ResponseLine.objects.filter(printer=printer)
        .order_by("seq")
        .values_list("seq", flat=True)
    )


def test_each_printer_keeps_its_newest_lines_up_to_its_own_limit(
    make_printer: Callable[..., Printer],
) -> None:
    over = make_printer(response_log_limit=10)
    at_limit = make_printer(response_log_limit=25)
    under = make_printer(response_log_limit=100)
    for printer in (over, at_limit, under):
        log_lines(printer, 25)

    # A batch of 4 rows per statement: 15 lines go in four statements.
    assert trim_response_logs(batch=4) == {"lines": 15}

    assert kept(over) == list(range(16, 26))
    assert kept(at_limit) == list(range(1, 26))
    assert kept(under) == list(range(1, 26))
    assert trim_response_logs() == {"lines": 0}


def test_the_newest_lines_are_kept_when_old_ids_are_already_gone(
    make_printer: Callable[..., Printer],
) -> None:
    printer = make_printer(response_log_limit=5)
    log_lines(printer, 30)
    ResponseLine.objects.filter(printer=printer, seq__lte=20).delete()

    assert trim_response_logs(batch=3) == {"lines": 5}
    assert kept(printer) == [26, 27, 28, 29, 30]


def test_a_limit_of_0_keeps_no_line_as_the_worker_did(
    make_printer: Callable[..., Printer],
) -> None:
    printer = make_printer(response_log_limit=0)
    log_lines(printer, 7)
    assert trim_response_logs() == {"lines": 7}
    assert kept(printer) == []


def test_the_worker_loop_writes_lines_and_deletes_none(
    make_printer: Callable[..., Printer],
) -> None:
    printer = make_printer(response_log_limit=10)
    log = ResponseLog(printer.pk)
    for i in range(25):
        log.add(f"line {i}", LineKind.COMMAND)
    for now in (0.0, 31.0, 62.0, 600.0):  # the old loop trimmed every 30 s
        log.flush_if_due(now)
    assert kept(printer) == list(range(1, 26))
