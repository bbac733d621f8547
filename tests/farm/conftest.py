"""Farm fixtures: printers the farm may use, files of a known size, uploads to the farm.

A printer is made ready the way its worker leaves it (state idle, its lease held);
a farm file is analysed by the real analyser, in this process, as the Celery task
would (`jobs.analysis_task.run`).
"""

from __future__ import annotations

import io
from datetime import timedelta
from typing import TYPE_CHECKING, Any

import pytest
from django.utils import timezone

if TYPE_CHECKING:
    from collections.abc import Callable

    from jobs.farm.models import FarmJob
    from printers.models import Printer

#: A Prusa MK3-sized build volume, and a large one.
MK3 = {"min": [0, -4, 0], "max": [250, 210, 210]}
BIG = {"min": [0, 0, 0], "max": [350, 350, 340]}


def box_gcode(width: float, depth: float, height: float, *, at: float = 10) -> str:
    """A part that extrudes the outline of a *width* x *depth* x *height* mm box,
    its corner at (*at*, *at*), two layers: the bottom and the top."""
    x0, y0, x1, y1 = at, at, at + width, at + depth
    lines = ["G28", "G90", "M82", "G92 E0", "G1 Z0.2 F600"]
    e = 0.0
    for z in (0.2, height):
        lines += [f"G1 Z{z:g} F600", f"G0 X{x0:g} Y{y0:g} F6000"]
        for x, y in ((x1, y0), (x1, y1), (x0, y1), (x0, y0)):
            e += 1
            lines.append(f"G1 X{x:g} Y{y:g} E{e:g} F1800")
    lines.append("M84")
    return "\n".join(lines) + "\n"


def make_ready(printer: Printer, **fields: Any) -> Printer:
    """The printer as its worker leaves it when it can take a job: connected, the
    bed confirmed clear (idle), its lease held."""
    from printers.models import Printer

    values = {
        "state": Printer.State.IDLE,
        "lease_owner": "test-worker",
        "lease_expires_at": timezone.now() + timedelta(hours=1),
        **fields,
    }
    Printer.objects.filter(pk=printer.pk).update(**values)
    printer.refresh_from_db()
    return printer


@pytest.fixture
def farm_printer(make_printer: Callable[..., Printer]) -> Callable[..., Printer]:
    """A ready farm printer with an MK3's volume; keywords override its fields."""

    def factory(slug: str, **fields: Any) -> Printer:
        values: dict[str, Any] = {"build_volume": MK3, "material": "PLA", **fields}
        runtime = ("state", "lease_owner", "lease_expires_at")
        state = {k: values.pop(k) for k in runtime if k in values}
        return make_ready(make_printer(slug=slug, name=slug.upper(), **values), **state)

    return factory


@pytest.fixture
def to_farm(db: None, storage: object) -> Callable[..., FarmJob]:
    """Upload *text* to the farm queue (the real storing path), analysed unless
    *analyse* is false."""
    from jobs.analysis_task import run
    from jobs.farm.requirements import parse_requirements
    from jobs.farm.storing import store_farm_upload

    def factory(
        text: str, name: str = "part.gcode", *, analyse: bool = True, **asks: Any
    ) -> FarmJob:
        priority = asks.pop("priority", 0)
        deadline = asks.pop("deadline", None)
        farm_job = store_farm_upload(
            io.BytesIO(text.encode()),
            name=name,
            requirements=parse_requirements(asks),
            priority=priority,
            deadline=deadline,
            origin="test",
        )
        if analyse:
            assert run(farm_job.analysis_id, worker="test") in ("done", "skipped")
        farm_job.refresh_from_db()
        return farm_job

    return factory
