"""A printer's build volume (what a farm job's part must fit) is checked before it
is stored: the admin's JSON field reads `Infinity`, and a volume of infinite size
would take every part and spoil the farm's smallest-first order."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest
from django.core.exceptions import ValidationError
from django.db import models

if TYPE_CHECKING:
    from collections.abc import Callable

    from printers.models import Printer

pytestmark = pytest.mark.django_db


def field() -> models.Field:
    """Printer.build_volume, as the admin's form cleans it (its validators)."""
    from printers.models import Printer

    return Printer._meta.get_field("build_volume")


INF, NAN = float("inf"), float("nan")


@pytest.mark.parametrize(
    "volume",
    [
        {"min": [0, 0, 0], "max": [INF, 210, 210]},
        {"min": [-INF, 0, 0], "max": [250, 210, 210]},
        {"min": [0, 0, 0], "max": [250, NAN, 210]},
        {"min": [0, 0, 0], "max": [1e308, 210, 210]},
        {"min": [0, 0, 0], "max": [250, 210]},
        {"min": [0, 0, 0], "max": [250, 210, True]},
        {"min": [10, 0, 0], "max": [5, 210, 210]},
    ],
)
def test_a_build_volume_beyond_reason_is_refused(
    make_printer: Callable[..., Printer], volume: dict
) -> None:
    printer = make_printer()
    with pytest.raises(ValidationError, match=r"build volume|numbers|mm"):
        field().clean(volume, printer)


def test_a_ten_metre_build_volume_is_taken(
    make_printer: Callable[..., Printer],
) -> None:
    volume = {"min": [-10_000, 0, 0], "max": [10_000, 3000, 2000]}
    assert field().clean(volume, make_printer()) == volume
