"""Each page's first render stays under 300 KB: HTML plus every CSS and JS it loads.

Printers sit on slow, offline networks: no CDN, no framework, system fonts.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from django.contrib.auth import get_user_model
from django.contrib.staticfiles import finders

from printhost.models import PrinterRole, Role

if TYPE_CHECKING:
    from collections.abc import Callable

    from django.test import Client

LIMIT = 300 * 1024
ASSET = re.compile(r'(?:src|href)="/static/([^"]+)"')
IMPORT = re.compile(r'from\s+"\./([^"]+)"')


def static_size(name: str, seen: set[str]) -> int:
    """Bytes of one static file plus the modules it imports (each counted once)."""
    if name in seen:
        return 0
    seen.add(name)
    found = finders.find(name)
    assert found, f"static file {name} is referenced but not found"
    path = Path(found)
    size = path.stat().st_size
    if name.endswith(".js"):
        folder = name.rsplit("/", 1)[0]
        for module in IMPORT.findall(path.read_text()):
            size += static_size(f"{folder}/{module}", seen)
    return size


@pytest.fixture
def logged_in(
    client: Client, make_printer: Callable[..., Any], make_job: Callable[..., Any]
) -> dict[str, str]:
    printer = make_printer(name="Prusa", slug="prusa")
    make_printer(name="Mill", slug="mill", firmware="grbl")
    job = make_job(printer, "G28\n" * 100)
    user = get_user_model().objects.create_user("op", password="op")
    PrinterRole.objects.create(user=user, printer=None, role=Role.OPERATOR)
    client.force_login(user)
    return {
        "dashboard": "/",
        "printer": "/printers/prusa/",
        "grbl printer": "/printers/mill/",
        "job": f"/jobs/{job.pk}/",
        "account": "/account/",
    }


def test_every_page_weighs_at_most_300_kb(
    client: Client, logged_in: dict[str, str]
) -> None:
    for page, url in logged_in.items():
        response = client.get(url)
        assert response.status_code == 200, page
        html = response.content.decode()
        seen: set[str] = set()
        assets = sum(static_size(name, seen) for name in ASSET.findall(html))
        assert any(n.endswith(".css") for n in seen), f"{page}: no stylesheet found"
        total = len(response.content) + assets
        assert total <= LIMIT, f"{page}: {total} bytes"


def test_pages_load_nothing_from_other_sites(
    client: Client, logged_in: dict[str, str]
) -> None:
    for page, url in logged_in.items():
        html = client.get(url).content.decode()
        assert not re.search(r'(?:src|href)="(?:https?:)?//', html), page
