"""runhost starts the terminal server only when some printer has a terminal port."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from printers.models import Printer
from printers.supervisor import Supervisor

pytestmark = pytest.mark.django_db


def test_no_terminal_process_without_a_terminal_port(
    make_printer: Callable[..., Printer],
) -> None:
    make_printer(slug="a")
    assert "terminal" not in Supervisor(bind="", port=0, serve_web=False).wanted()


def test_one_terminal_process_serves_every_printer_with_a_port(
    make_printer: Callable[..., Printer],
) -> None:
    make_printer(slug="a", terminal_port=23001)
    make_printer(slug="b", terminal_port=23002)
    make_printer(slug="off", terminal_port=23003, enabled=False)
    wanted = Supervisor(bind="", port=0, serve_web=False).wanted()
    assert wanted["terminal"][-1] == "run_terminal"
    assert [name for name in wanted if name.startswith("terminal")] == ["terminal"]
    names = list(wanted)
    assert names.index("terminal") < names.index("worker:a"), "terminal before workers"
