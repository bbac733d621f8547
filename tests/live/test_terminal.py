"""The raw TCP terminal against a real runhost: key line, output, commands, refusals."""

from __future__ import annotations

import socket
import time
from pathlib import Path

import pytest

from tests.conftest import wait_for
from tests.hosts import Host, free_port

pytestmark = pytest.mark.slow


class Terminal:
    """A plain TCP client, as netcat or Pronterface would be."""

    def __init__(self, port: int, key: str) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=10)
        self.buffer = b""
        self.send(key)

    def send(self, line: str) -> None:
        self.sock.sendall(f"{line}\n".encode())

    def readline(self, timeout: float = 20) -> str | None:
        """The next line, or None when the server closed the connection."""
        deadline = time.monotonic() + timeout
        while b"\n" not in self.buffer:
            self.sock.settimeout(max(0.01, deadline - time.monotonic()))
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                raise AssertionError(f"no line within {timeout} s") from None
            if not data:
                return None
            self.buffer += data
        line, _, self.buffer = self.buffer.partition(b"\n")
        return line.decode()

    def read_until(self, text: str, timeout: float = 30) -> list[str]:
        seen: list[str] = []
        deadline = time.monotonic() + timeout
        while not seen or text not in seen[-1]:
            line = self.readline(max(0.1, deadline - time.monotonic()))
            assert line is not None, f"closed before {text!r}; got {seen[-5:]}"
            seen.append(line)
        return seen

    def close(self) -> None:
        self.sock.close()


def test_the_terminal_streams_output_takes_commands_and_refuses_bad_keys(
    tmp_path: Path,
) -> None:
    host = Host(tmp_path)
    host.migrate()
    port = free_port()
    record = host.add_simulated_printer("p1", terminal_port=port)
    host.add_simulated_printer("p2")
    operator = host.add_user("op", "operator", printer="p1")
    viewer = host.add_user("viewer", "viewer", printer="p1")
    stranger = host.add_user("stranger", "operator", printer="p2")
    bound = host.add_user("bound", "operator", key_printer="p2")

    with host.running():
        wait_for(lambda: _accepts(port), 30, "the terminal to listen")
        wait_for(
            lambda: host.query("SELECT state FROM printers_printer WHERE slug='p1'")
            == [("idle",)],
            30, "p1 to be idle",
        )  # fmt: skip
        for key, error in [
            ("ph_notakeyatall0000", "error: invalid API key"),
            ("", "error: invalid API key"),
            (stranger, "error: this key may not watch printer 'p1'"),
            (bound, "error: this key may not watch printer 'p1'"),
        ]:
            refused = Terminal(port, key)
            assert refused.readline() == error
            assert refused.readline() is None, "the connection is closed"
            refused.close()

        watching = Terminal(port, viewer)
        assert watching.readline() == "// printhost: p1 as viewer (viewer)"
        watching.send("G28")
        assert watching.readline().startswith("error: operator role needed")

        terminal = Terminal(port, operator)
        assert terminal.readline() == "// printhost: p1 as op (operator)"
        terminal.send("M117 hello from a terminal")
        terminal.read_until("M117 hello from a terminal")
        # Every client gets the printer's output, the viewer too.
        watching.read_until("M117 hello from a terminal")
        terminal.send("[ESP701]")
        terminal.read_until("status: idle")
        terminal.close()
        watching.close()

    ran = record.read_text().splitlines()
    assert "M117 hello from a terminal" in ran
    assert "G28" not in ran, "the viewer's command never reached the printer"
    audit = host.query("SELECT action, detail FROM printhost_auditentry")
    assert ("command", "M117 hello from a terminal") in audit


def _accepts(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.5):
            return True
    except OSError:
        return False
