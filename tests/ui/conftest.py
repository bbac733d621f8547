"""Browser fixtures: the system Chromium driven by Playwright against a running host.

We never download a browser: Chromium is Debian's `chromium` package (CI installs
it in `.ci/run`), given to Playwright by path. Each test module gets one running
printhost (`Host.running()`: daphne, simulators, workers) and one browser; pages are
opened per viewport and fail the test on any JavaScript console error.
"""

from __future__ import annotations

import importlib
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from tests.conftest import ROOT
from tests.hosts import Host, services_required

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from types import ModuleType

    from playwright.sync_api import Browser, BrowserContext, ConsoleMessage, Page

#: Where the tests write the screenshots the README shows (committed by hand).
SCREENSHOTS = ROOT / "docs" / "screenshots"

#: The two sizes every page must work at.
VIEWPORTS: dict[str, dict[str, object]] = {
    "phone": {
        "viewport": {"width": 390, "height": 844},
        "is_mobile": True,
        "has_touch": True,
        "device_scale_factor": 2,
    },
    "tablet": {
        "viewport": {"width": 1024, "height": 768},
        "device_scale_factor": 1,
    },
}

#: Passwords are the user names (tests.hosts.Host.add_user).
OPERATOR, VIEWER, STRANGER = "olga", "victor", "stan"

#: Bounds of the waits in browser tests (a print is a few seconds on the simulator).
STEP_MS = 15_000
PRINT_MS = 60_000


def skip_or_fail(message: str) -> None:
    """Skip locally; fail in CI (PRINTHOST_REQUIRE_SERVICES=1), which has it all."""
    if services_required():
        pytest.fail(message)
    pytest.skip(message, allow_module_level=True)


def playwright_api() -> ModuleType:
    """playwright.sync_api, or skip (fail in CI) when requirements-dev is missing."""
    try:
        return importlib.import_module("playwright.sync_api")
    except ImportError:
        skip_or_fail(
            "playwright is not installed (pip install -r requirements-dev.txt)"
        )
        raise


@pytest.fixture(scope="session")
def chromium_path() -> str:
    """Debian's Chromium, or skip (fail in CI, which installs it)."""
    path = os.environ.get("PRINTHOST_CHROMIUM", "/usr/bin/chromium")
    if not Path(path).is_file():
        message = (
            f"Chromium is not installed (Debian package chromium; looked for {path},"
            " set PRINTHOST_CHROMIUM to use another)"
        )
        skip_or_fail(message)
    return path


@pytest.fixture(scope="module")
def browser(chromium_path: str) -> Iterator[Browser]:
    """One headless Chromium per module.

    Module scope, not session: Playwright's sync API leaves an event loop marked
    running on this thread, and Django refuses database access while it is, so it
    must be gone before other modules' tests touch the test database.
    """
    sync_api = playwright_api()
    args = ["--no-sandbox"] if os.geteuid() == 0 else []
    with sync_api.sync_playwright() as playwright:
        launched = playwright.chromium.launch(
            executable_path=chromium_path, headless=True, args=args
        )
        try:
            yield launched
        finally:
            launched.close()


@dataclass
class LiveHost:
    """A running printhost with simulated printers and users of each role."""

    host: Host
    records: dict[str, Path]
    folder: Path

    @property
    def url(self) -> str:
        return self.host.url

    def record(self, slug: str) -> str:
        """Commands the simulator of *slug* executed so far."""
        path = self.records[slug]
        return path.read_text(errors="replace") if path.exists() else ""

    def job_ids(self, slug: str) -> list[int]:
        return [
            row[0]
            for row in self.host.query(
                "SELECT j.id FROM jobs_job j JOIN printers_printer p"
                f" ON p.id = j.printer_id WHERE p.slug = '{slug}' ORDER BY j.id"
            )
        ]


def start_live_host(
    folder: Path,
    printers: dict[str, str],
    jobs: dict[str, str] | None = None,
    *,
    celery: bool = False,
) -> Iterator[LiveHost]:
    """Set up *printers* (slug -> simulator arguments; "" = no simulator, offline),
    an operator and a viewer on the first printer, a user with no role, queue
    *jobs* (slug -> G-code text), and run it until the generator is closed."""
    host = Host(folder)
    host.migrate()
    records: dict[str, Path] = {}
    for slug, sim_args in printers.items():
        if sim_args:
            # Temperatures reported every second, so pages and screenshots show them.
            records[slug] = host.add_simulated_printer(
                slug, sim_args=sim_args, temperature_interval=1.0
            )
        else:
            host.shell(
                "from printers.models import Printer; Printer.objects.create("
                f"name={slug.upper()!r}, slug={slug!r}, port='/nonexistent')"
            )
    first = next(iter(printers))
    host.add_users(
        [(OPERATOR, "operator", ""), (VIEWER, "viewer", first), (STRANGER, "", "")]
    )
    for slug, text in (jobs or {}).items():
        source = folder / f"{slug}-first.gcode"
        source.write_text(text)
        host.manage("add_job", slug, str(source), "--name", "first.gcode")
    with host.running(celery=celery):
        yield LiveHost(host, records, folder)


@dataclass
class Tab:
    """A page at one viewport, with the console errors it logged."""

    page: Page
    size: str
    base: str
    errors: list[str] = field(default_factory=list)
    allowed: list[re.Pattern[str]] = field(default_factory=list)

    def go(self, path: str) -> None:
        response = self.page.goto(self.base + path, wait_until="load")
        assert response is not None, path
        assert response.status == 200, f"{path}: {response.status}"

    def allow_console(self, pattern: str) -> None:
        """Let an expected console error through (Chromium logs failed requests)."""
        self.allowed.append(re.compile(pattern))

    def unexpected_errors(self) -> list[str]:
        return [e for e in self.errors if not any(a.search(e) for a in self.allowed)]

    def screenshot(self, name: str, *, top: str = "") -> Path:
        """docs/screenshots/<name>-<size>.png: the README shows some of them. With
        *top* (a data-test), the page is scrolled to that element first."""
        SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        path = SCREENSHOTS / f"{name}-{self.size}.png"
        if top:
            self.page.locator(f"[data-test={top}]").first.evaluate(
                "el => window.scrollTo(0, el.getBoundingClientRect().top + window.scrollY - 8)"
            )
        else:
            self.page.evaluate("() => window.scrollTo(0, 0)")
        # The simulator's port is a path in a temporary folder of this machine.
        port = self.page.locator("[data-test=port]")
        self.page.screenshot(path=str(path), mask=[port], mask_color="#8889")
        return path


@pytest.fixture
def open_tab(browser: Browser) -> Iterator[Callable[..., Tab]]:
    """Open pages (a fresh context each: no cookies, no cache) at a viewport.

    Every console error and uncaught exception is collected; the test fails at
    teardown if any appeared that it did not expect.
    """
    contexts: list[BrowserContext] = []
    tabs: list[Tab] = []

    def factory(base: str, size: str) -> Tab:
        context = browser.new_context(**VIEWPORTS[size])  # type: ignore[arg-type]
        context.set_default_timeout(STEP_MS)
        contexts.append(context)
        page = context.new_page()
        tab = Tab(page, size, base)

        def on_console(message: ConsoleMessage) -> None:
            if message.type == "error":
                where = message.location.get("url", "")
                tab.errors.append(f"console: {message.text} ({where})")

        page.on("console", on_console)
        page.on("pageerror", lambda error: tab.errors.append(f"uncaught: {error}"))
        # A confirm() before a stop or a delete is answered yes, as a user would.
        page.on("dialog", lambda dialog: dialog.accept())
        tabs.append(tab)
        return tab

    yield factory
    errors = [f"[{t.size}] {e}" for t in tabs for e in t.unexpected_errors()]
    for context in contexts:
        context.close()
    assert not errors, "JavaScript console errors:\n" + "\n".join(errors)


def log_in(tab: Tab, username: str, next_path: str = "/") -> None:
    """Log in through the login form, as a person would."""
    tab.page.goto(f"{tab.base}/accounts/login/?next={next_path}", wait_until="load")
    tab.page.fill("#id_username", username)
    tab.page.fill("#id_password", username)
    with tab.page.expect_navigation(wait_until="load"):
        tab.page.click("button[type=submit]")
    assert "/accounts/login/" not in tab.page.url, f"login failed for {username}"
