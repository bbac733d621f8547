"""A browser's live feed ends within seconds of its session ending.

Real `runhost`, real HTTP login and logout (httpx), a real websocket (the
`websockets` package) carrying the session cookie and the page's Origin, as a
browser's would. The consumers re-check their caller every `RECONCILE_SECONDS`.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

import httpx
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from printers.live import RECONCILE_SECONDS
from tests.hosts import Host
from tests.security.browsers import browser_login, browser_logout

pytestmark = pytest.mark.slow

#: Generous: the re-check runs every 5 s; a noisy machine may be slow.
CLOSE_WITHIN = 40.0


@pytest.fixture(scope="module")
def host(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Host]:
    host = Host(tmp_path_factory.mktemp("wssessions"))
    host.migrate()
    host.add_simulated_printer("mk3")
    for name in ("ann", "bob", "cy"):
        host.add_user(name, role="viewer")
    with host.running():
        yield host


@contextmanager
def live_feed(
    host: Host, browser: httpx.Client, path: str
) -> Iterator[ClientConnection]:
    """The page's websocket: the session cookie and the page's own Origin."""
    with connect(
        f"ws://127.0.0.1:{host.port}{path}",
        origin=host.url,  # type: ignore[arg-type]
        additional_headers={"Cookie": f"sessionid={browser.cookies['sessionid']}"},
        open_timeout=30,
    ) as socket:
        hello = socket.recv(timeout=30)
        assert '"hello"' in str(hello), hello
        yield socket


def close_code(socket: ClientConnection, within: float) -> int:
    """Read messages until the server closes; its close code."""
    try:
        while True:
            socket.recv(timeout=within)
    except ConnectionClosed as closed:
        assert closed.rcvd is not None, "closed without a close frame"
        return closed.rcvd.code
    except TimeoutError:
        raise AssertionError(f"still open after {within} s") from None


def stays_open(socket: ClientConnection, seconds: float) -> bool:
    """Read whatever comes for *seconds*; False if the server closed meanwhile."""
    deadline = time.monotonic() + seconds
    try:
        while (left := deadline - time.monotonic()) > 0:
            socket.recv(timeout=left)
    except TimeoutError:
        return True
    except ConnectionClosed:
        return False
    return True


@pytest.mark.parametrize("path", ["/ws/printers/mk3/", "/ws/printers/"])
def test_the_live_feed_of_a_user_who_logged_out_closes_with_4401(
    host: Host, path: str
) -> None:
    browser = browser_login(host, "ann")
    with live_feed(host, browser, path) as socket:
        browser_logout(browser)
        assert close_code(socket, CLOSE_WITHIN) == 4401


def test_the_live_feed_of_a_deactivated_user_closes_with_4401(host: Host) -> None:
    browser = browser_login(host, "bob")
    with live_feed(host, browser, "/ws/printers/mk3/") as socket:
        host.shell(
            "from django.contrib.auth import get_user_model; "
            "get_user_model().objects.filter(username='bob').update(is_active=False)"
        )
        assert close_code(socket, CLOSE_WITHIN) == 4401


#: How a session ends without its user logging out: flushed, or past its expiry.
ENDINGS = {
    "flushed": "delete()",
    "expired": "update(expire_date=timezone.now() - timedelta(seconds=1))",
}


@pytest.mark.parametrize("ending", ENDINGS)
def test_the_live_feed_of_an_ended_session_closes_and_others_stay(
    host: Host, ending: str
) -> None:
    gone, kept = browser_login(host, "cy"), browser_login(host, "cy")
    session = gone.cookies["sessionid"]
    with (
        live_feed(host, gone, "/ws/printers/mk3/") as closing,
        live_feed(host, kept, "/ws/printers/mk3/") as staying,
    ):
        host.shell(
            "from datetime import timedelta; from django.utils import timezone; "
            "from django.contrib.sessions.models import Session; "
            f"Session.objects.filter(session_key={session!r}).{ENDINGS[ending]}"
        )
        assert close_code(closing, CLOSE_WITHIN) == 4401
        # The same user's other session is untouched: it outlives two re-checks.
        assert stays_open(staying, 2 * RECONCILE_SECONDS + 1)
