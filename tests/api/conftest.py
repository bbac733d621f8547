"""Fixtures of the API tests: a printer and API keys with a role."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest
from django.contrib.auth import get_user_model

from printers.models import Printer
from printhost.access import issue_key
from printhost.models import PrinterRole, Role

if TYPE_CHECKING:
    from collections.abc import Callable


@pytest.fixture
def printer(make_printer: Callable[..., Printer]) -> Printer:
    return make_printer(slug="mk3", name="MK3", state=Printer.State.IDLE)


@pytest.fixture
def keys(db: None, printer: Printer) -> Callable[..., str]:
    """A raw API key for a fresh user holding *role* (on every printer)."""

    def make(role: str = "operator", *, bound: Printer | None = None) -> str:
        count = get_user_model().objects.count()
        user = get_user_model().objects.create_user(f"{role}{count}")
        PrinterRole.objects.create(user=user, role=Role[role.upper()], printer=None)
        return issue_key(user, "test", printer=bound)[1]

    return make
