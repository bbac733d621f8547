"""The raw TCP terminal's limits against a real runhost, over real TCP.

Connection caps (per printer port, per client address: the excess gets one line and
is closed), clients that never log in, over-long and endless lines (refused,
discarded, memory stays small), commands longer than the firmware takes, and
control characters in what the printer says (never written to a client).
"""

from __future__ import annotations

import socket
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from tests.conftest import wait_for
from tests.hosts import Host, free_port
from tests.live.test_terminal import Terminal, _accepts

if TYPE_CHECKING:
    from collections.abc import Iterator

pytestmark = pytest.mark.slow

MAX_CLIENTS = 3
MAX_PER_ADDRESS = 2
#: Peak memory the terminal process may reach after an endless line (generous).
RSS_LIMIT = 200 * 1024**2
ENDLESS = 64 * 1024**2


class From(Terminal):
    """A terminal client connecting from a chosen loopback address."""

    def __init__(self, port: int, key: str | None, source: str = "127.0.0.1") -> None:
        self.sock = socket.create_connection(
            ("127.0.0.1", port), timeout=10, source_address=(source, 0)
        )
        self.buffer = b""
        if key is not None:
            self.send(key)


class Served:
    def __init__(self, host: Host, port: int, operator: str) -> None:
        self.host, self.port, self.operator = host, port, operator

    def login(self, source: str = "127.0.0.1") -> From:
        client = From(self.port, self.operator, source)
        assert client.readline() == "// printhost: p1 as op (operator)"
        return client


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    host = Host(tmp_path_factory.mktemp("terminal"))
    host.env.update(
        PRINTHOST_TERMINAL_MAX_CLIENTS=str(MAX_CLIENTS),
        PRINTHOST_TERMINAL_MAX_PER_ADDRESS=str(MAX_PER_ADDRESS),
        PRINTHOST_TERMINAL_LOGIN_SECONDS="2",
    )
    host.migrate()
    port = free_port()
    host.add_simulated_printer("p1", terminal_port=port)
    operator = host.add_user("op", "operator", printer="p1")
    with host.running(web=False) as runhost:
        wait_for(lambda: _accepts(port), 30, "the terminal to listen")
        wait_for(
            lambda: host.query("SELECT state FROM printers_printer WHERE slug='p1'")
            == [("idle",)],
            30, "p1 to be idle",
        )  # fmt: skip
        served = Served(host, port, operator)
        served.runhost = runhost.pid  # type: ignore[attr-defined]
        yield served


def terminal_pid(runhost: int) -> int:
    for child in Path(f"/proc/{runhost}/task/{runhost}/children").read_text().split():
        command = Path(f"/proc/{child}/cmdline").read_bytes().split(b"\0")
        if b"run_terminal" in command:
            return int(child)
    raise AssertionError("no run_terminal process under runhost")


def peak_rss(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise AssertionError("no VmHWM")


def test_connections_past_the_caps_get_one_line_and_are_closed(served: Served) -> None:
    clients = [served.login(), served.login()]
    try:
        third = From(served.port, None)
        assert third.readline() == (
            "error: too many terminal connections from 127.0.0.1 "
            f"(at most {MAX_PER_ADDRESS}); try again later"
        )
        assert third.readline() is None
        third.close()

        clients.append(served.login("127.0.0.2"))
        fourth = From(served.port, None, "127.0.0.3")
        assert fourth.readline() == (
            f"error: too many terminal clients on printer 'p1' (at most {MAX_CLIENTS})"
            "; try again later"
        )
        assert fourth.readline() is None
        fourth.close()

        clients.pop(0).close()

        def let_in_again() -> bool:
            client = From(served.port, served.operator)
            line = client.readline()
            if line == "// printhost: p1 as op (operator)":
                clients.append(client)
                return True
            client.close()
            return False

        wait_for(let_in_again, 30, "a place given back when a client leaves")
    finally:
        for client in clients:
            client.close()


def settled(served: Served) -> None:
    """Until the terminal has seen earlier tests' clients leave (they closed their end
    just before; the server counts them until it reads their end of file)."""

    def not_refused() -> bool:
        probe = From(served.port, None, "127.0.0.9")
        try:
            probe.readline(timeout=0.3)
        except AssertionError:  # no line: not refused, waiting for a key
            return True
        finally:
            probe.close()
        return False

    wait_for(not_refused, 30, "earlier clients to be let go")


def test_a_client_that_gives_no_key_in_time_is_closed(served: Served) -> None:
    settled(served)
    silent = From(served.port, None, "127.0.0.4")
    trickling = From(served.port, None, "127.0.0.5")
    trickling.sock.sendall(b"ph_")
    for client in (silent, trickling):
        assert client.readline(timeout=60) == "error: no API key given in time"
        assert client.readline() is None
        client.close()


def test_connections_that_never_log_in_cannot_keep_a_user_out(served: Served) -> None:
    settled(served)
    # As many silent connections as clients may log in, from two addresses (each
    # under its own cap): the next connection, a user's, still gets in.
    silent = [From(served.port, None, address)
              for address in ("127.0.0.6", "127.0.0.6", "127.0.0.7")]  # fmt: skip
    user = served.login("127.0.0.8")
    try:
        assert silent[0].readline() == "error: too many connections waiting to log in"
        assert silent[0].readline() is None
        user.send("M117 let in")
        user.read_until("M117 let in")
    finally:
        for client in (*silent, user):
            client.close()


def test_over_long_lines_are_refused_and_the_session_goes_on(served: Served) -> None:
    client = served.login()
    try:
        client.sock.sendall(b"M117 " + b"x" * 10000 + b"\n")
        assert client.read_until("error:")[-1] == (
            "error: line longer than 4096 bytes, discarded"
        )
        client.send("M117 " + "y" * 200)
        assert client.read_until("error:")[-1] == (
            "error: command longer than 81 characters, the most this printer's "
            "firmware takes; not sent"
        )
        client.send("M117 still here")
        client.read_until("M117 still here")
    finally:
        client.close()
    ran = served.host.query("SELECT text FROM printers_responseline")
    assert not [t for (t,) in ran if "xxxx" in t or "yyyy" in t]


def test_an_endless_line_is_discarded_without_growing_memory(served: Served) -> None:
    client = served.login()
    try:
        piece = b"G1 X1" * 13107
        sent = 0
        while sent < ENDLESS:
            client.sock.sendall(piece)
            sent += len(piece)
        client.sock.sendall(b"\nM117 after the flood\n")
        assert client.read_until("error:")[-1] == (
            "error: line longer than 4096 bytes, discarded"
        )
        client.read_until("M117 after the flood")
    finally:
        client.close()
    assert peak_rss(terminal_pid(served.runhost)) < RSS_LIMIT  # type: ignore[attr-defined]


#: What a printer (a board's LCD message, a hostile firmware) might say: OSC title,
#: clear screen, colours, a bell, DEL and a C1 CSI; printhost cannot make the
#: simulator say it (commands must be printable ASCII), so it is written to the
#: printer's response log as the worker writes what a printer says.
HOSTILE = "echo:\x1b]0;owned\x07 \x1b[2J\x1b[31mred\tok\x7f\x9b6n\r"


def test_control_characters_from_the_printer_never_reach_a_client(
    served: Served,
) -> None:
    client = served.login()
    try:
        served.host.shell(
            "from django.db.models import Max; from django.utils import timezone\n"
            "from printers.models import Printer, ResponseLine\n"
            "p = Printer.objects.get(slug='p1')\n"
            "seq = (ResponseLine.objects.filter(printer=p).aggregate(m=Max('seq'))"
            "['m'] or 0) + 1\n"
            f"ResponseLine.objects.create(printer=p, seq=seq, time=timezone.now(), "
            f"text={HOSTILE!r}, kind=4)"
        )
        line = client.read_until("red")[-1]
    finally:
        client.close()
    assert line == "echo:]0;owned [2J[31mred\tok6n"
