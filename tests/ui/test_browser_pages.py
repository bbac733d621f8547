"""Every page in real Chromium at phone and tablet size: fits, light, usable by touch.

And the roles: anonymous users go to the login page, users without a role on a
printer get the 403 page, viewers see no controls; a failed action shows the API's
message.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from printers.sample_gcode import segments
from tests.ui.conftest import (
    OPERATOR,
    STRANGER,
    VIEWER,
    VIEWPORTS,
    LiveHost,
    Tab,
    log_in,
    playwright_api,
    start_live_host,
)

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

    from playwright.sync_api import Browser

pytestmark = pytest.mark.slow

expect = playwright_api().expect

#: The printer everyone in these tests may see, and one only the operator may.
MINE, OTHER = "alpha", "beta"

#: Largest first render of a page (HTML, CSS, JS, fonts, images) on localhost.
MAX_FIRST_RENDER_BYTES = 300 * 1024

#: Smallest touch target, CSS pixels.
MIN_TARGET = 44

#: Controls in the page's content smaller than MIN_TARGET (a checkbox or radio is
#: measured with its label, which is what a finger hits).
SMALL_TARGETS = """min => {
  const picked = document.querySelectorAll(
    'main button, main a[href], main input:not([type=hidden]), main select,'
    + ' main summary, main textarea, [data-test=estop], [data-test=user-menu]');
  const small = [];
  for (const el of picked) {
    const style = getComputedStyle(el);
    if (style.visibility === 'hidden' || el.getClientRects().length === 0) continue;
    let box = el.getBoundingClientRect();
    if (el.matches('input[type=checkbox], input[type=radio]') && el.closest('label')) {
      box = el.closest('label').getBoundingClientRect();
    }
    // Links inside a sentence or a definition are exempt (WCAG 2.5.5 inline targets).
    if (el.matches('main p a, main dd a') && !el.dataset.test) continue;
    if (box.width < min || box.height < min) {
      const name = el.dataset.test || el.id || el.getAttribute('aria-label')
        || (el.textContent || '').trim().slice(0, 30) || el.outerHTML.slice(0, 60);
      small.push(`${name} ${Math.round(box.width)}x${Math.round(box.height)}`);
    }
  }
  return small;
}"""


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveHost]:
    folder = tmp_path_factory.mktemp("browser-pages")
    yield from start_live_host(
        folder,
        {MINE: "--time-scale 0", OTHER: ""},
        jobs={MINE: segments(50)},
    )


@pytest.fixture(scope="module")
def job_id(live: LiveHost) -> int:
    return live.job_ids(MINE)[0]


def operator_pages(job: int) -> list[str]:
    return ["/", f"/printers/{MINE}/", f"/jobs/{job}/", "/account/"]


PAGES = ["login", "dashboard", "printer", "job", "account"]


def page_path(name: str, job: int) -> str:
    return {
        "login": "/accounts/login/",
        "dashboard": "/",
        "printer": f"/printers/{MINE}/",
        "job": f"/jobs/{job}/",
        "account": "/account/",
    }[name]


def first_render_bytes(tab: Tab, path: str) -> tuple[int, list[str]]:
    """Bytes on the wire (cache off) from navigation until the load event."""
    cdp = tab.page.context.new_cdp_session(tab.page)
    cdp.send("Network.enable")
    cdp.send("Network.setCacheDisabled", {"cacheDisabled": True})
    urls: dict[str, str] = {}
    sizes: dict[str, float] = {}
    cdp.on("Network.requestWillBeSent", lambda e: urls.update({e["requestId"]: e["request"]["url"]}))  # fmt: skip
    cdp.on("Network.loadingFinished", lambda e: sizes.update({e["requestId"]: e["encodedDataLength"]}))  # fmt: skip
    tab.go(path)
    cdp.detach()
    listing = [f"{int(n)} {urls.get(r, r)}" for r, n in sizes.items()]
    return int(sum(sizes.values())), listing


@pytest.mark.parametrize("size", list(VIEWPORTS))
@pytest.mark.parametrize("name", PAGES)
def test_page_fits_the_screen_has_big_targets_and_is_light(
    name: str, size: str, live: LiveHost, job_id: int, open_tab: Callable[..., Tab]
) -> None:
    tab = open_tab(live.url, size)
    if name != "login":
        log_in(tab, OPERATOR)
    total, listing = first_render_bytes(tab, page_path(name, job_id))
    assert total <= MAX_FIRST_RENDER_BYTES, (
        f"{name}: first render {total} bytes:\n" + "\n".join(listing)
    )
    page = tab.page
    page.wait_for_load_state("networkidle")
    width = page.evaluate("() => [document.documentElement.scrollWidth, innerWidth]")
    assert width[0] <= width[1], f"{name} scrolls sideways: {width[0]} > {width[1]}"
    small = page.evaluate(SMALL_TARGETS, MIN_TARGET)
    assert not small, f"{name}: touch targets under {MIN_TARGET} px: {small}"


def test_every_page_answers_by_role(
    live: LiveHost, job_id: int, browser: Browser
) -> None:
    """Operator 200 everywhere; anonymous 302 to the login page; no role: 403."""
    anonymous = browser.new_context()
    for path in operator_pages(job_id):
        answer = anonymous.request.get(live.url + path, max_redirects=0)
        assert answer.status == 302, f"anonymous {path}: {answer.status}"
        target = answer.headers["location"]
        assert target.startswith("/accounts/login/?next="), f"{path} -> {target}"
    anonymous.close()

    expected = {
        OPERATOR: dict.fromkeys(operator_pages(job_id), 200),
        VIEWER: {**dict.fromkeys(operator_pages(job_id), 200), f"/printers/{OTHER}/": 403},
        STRANGER: {"/": 200, "/account/": 200, f"/printers/{MINE}/": 403, f"/jobs/{job_id}/": 403},
    }  # fmt: skip
    for user, answers in expected.items():
        context = browser.new_context()
        page = context.new_page()
        log_in(Tab(page, "tablet", live.url), user)
        for path, status in answers.items():
            answer = context.request.get(live.url + path, max_redirects=0)
            assert answer.status == status, f"{user} {path}: {answer.status}"
            if status == 403:
                body = answer.text()
                assert "user-menu" in body, f"{user} {path}: not the styled 403 page"
        dashboard = context.request.get(live.url + "/").text()
        assert (f'data-printer="{MINE}"' in dashboard) == (user != STRANGER), user
        assert (f'data-printer="{OTHER}"' in dashboard) == (user == OPERATOR), user
        context.close()


@pytest.mark.parametrize("size", list(VIEWPORTS))
def test_anonymous_user_lands_on_the_login_page(
    size: str, live: LiveHost, open_tab: Callable[..., Tab]
) -> None:
    tab = open_tab(live.url, size)
    tab.page.goto(f"{live.url}/printers/{MINE}/", wait_until="load")
    assert "/accounts/login/?next=" in tab.page.url, tab.page.url
    expect(tab.page.locator("#id_username")).to_be_visible()
    expect(tab.page.locator("#id_password")).to_be_visible()


@pytest.mark.parametrize("size", list(VIEWPORTS))
def test_viewer_sees_the_printer_but_no_send_box_and_no_controls(
    size: str, live: LiveHost, open_tab: Callable[..., Tab]
) -> None:
    tab = open_tab(live.url, size)
    log_in(tab, VIEWER)
    tab.go(f"/printers/{MINE}/")
    page = tab.page
    expect(page.locator("[data-test=state]")).to_be_visible()
    expect(page.locator("[data-test=terminal]")).to_be_visible()
    expect(page.locator("[data-test=queue]")).to_be_visible()
    for hook in (
        "command",
        "send",
        "upload-file",
        "upload",
        "pause",
        "resume",
        "abort",
    ):
        for element in page.locator(f"[data-test={hook}]").all():
            assert not element.is_visible() or element.is_disabled(), (
                f"viewer can use [data-test={hook}]"
            )
    usable = page.locator(
        "[data-test=controls] button:visible:enabled,"
        " [data-test=controls] input:visible:enabled"
    )
    assert usable.count() == 0, "viewer can use the manual controls"


@pytest.mark.parametrize("size", list(VIEWPORTS))
def test_a_binary_upload_shows_the_api_message_and_stores_nothing(
    size: str, live: LiveHost, open_tab: Callable[..., Tab]
) -> None:
    tab = open_tab(live.url, size)
    # Chromium logs the refused request itself; that line is expected.
    tab.allow_console(
        r"Failed to load resource: the server responded with a status of 400"
    )
    log_in(tab, OPERATOR)
    tab.go(f"/printers/{MINE}/")
    page = tab.page
    before = live.job_ids(MINE)
    error = page.locator("[data-test=error]")
    expect(error).to_be_hidden()
    page.set_input_files(
        "[data-test=upload-file]",
        files=[
            {
                "name": "photo.gcode",
                "mimeType": "application/octet-stream",
                "buffer": b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR"
                + bytes(range(256)) * 8,
            }
        ],
    )
    page.locator("[data-test=upload]").click()
    expect(error).to_be_visible()
    expect(error).to_contain_text("binary")
    assert live.job_ids(MINE) == before


#: Text elements whose colour contrast with their background is under WCAG AA
#: (4.5:1, or 3:1 for large text). Disabled controls are exempt, as WCAG allows.
LOW_CONTRAST = """() => {
  const rgb = (css) => (css.match(/[\\d.]+/g) || []).map(Number);
  const lum = ([r, g, b]) => {
    const f = (c) => { c /= 255; return c <= 0.03928 ? c / 12.92 : ((c + 0.055) / 1.055) ** 2.4; };
    return 0.2126 * f(r) + 0.7152 * f(g) + 0.0722 * f(b);
  };
  const background = (el) => {
    for (let node = el; node; node = node.parentElement) {
      const c = rgb(getComputedStyle(node).backgroundColor);
      if (c.length === 3 || (c.length === 4 && c[3] > 0.5)) return c.slice(0, 3);
    }
    return matchMedia('(prefers-color-scheme: dark)').matches ? [0, 0, 0] : [255, 255, 255];
  };
  const low = [];
  for (const el of document.querySelectorAll('body *')) {
    const own = [...el.childNodes].some((n) => n.nodeType === 3 && n.textContent.trim());
    if (!own || el.getClientRects().length === 0 || el.closest(':disabled')) continue;
    const style = getComputedStyle(el);
    if (style.visibility === 'hidden' || Number(style.opacity) === 0) continue;
    const a = lum(rgb(style.color)), b = lum(background(el));
    const ratio = (Math.max(a, b) + 0.05) / (Math.min(a, b) + 0.05);
    const size = parseFloat(style.fontSize), bold = Number(style.fontWeight) >= 700;
    const need = size >= 24 || (bold && size >= 18.66) ? 3 : 4.5;
    if (ratio < need) low.push(`${el.tagName} "${el.textContent.trim().slice(0, 25)}" ${ratio.toFixed(2)}`);
  }
  return low;
}"""


@pytest.mark.parametrize("scheme", ["light", "dark"])
@pytest.mark.parametrize("name", ["login", "dashboard", "printer", "job", "account"])
def test_text_is_readable_in_light_and_dark_mode(
    name: str, scheme: str, live: LiveHost, job_id: int, open_tab: Callable[..., Tab]
) -> None:
    tab = open_tab(live.url, "tablet")
    tab.page.emulate_media(color_scheme=scheme)
    if name != "login":
        log_in(tab, OPERATOR)
    tab.go(page_path(name, job_id))
    tab.page.wait_for_load_state("networkidle")
    low = tab.page.evaluate(LOW_CONTRAST)
    assert not low, f"{name} ({scheme}): text under WCAG AA contrast: {low}"


def test_a_command_to_an_offline_printer_says_so_in_the_page(
    live: LiveHost, open_tab: Callable[..., Tab]
) -> None:
    tab = open_tab(live.url, "phone")
    # Chromium logs the refused request itself; that line is expected.
    tab.allow_console(
        r"Failed to load resource: the server responded with a status of 409"
    )
    log_in(tab, OPERATOR)
    tab.go(f"/printers/{OTHER}/")
    page = tab.page
    page.fill("[data-test=command]", "M105")
    page.locator("[data-test=send]").click()
    error = page.locator("[data-test=error]")
    expect(error).to_be_visible()
    expect(error).to_contain_text("offline")
