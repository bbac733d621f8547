"""SerialTransport.read(wake=...): another descriptor ends the wait (the worker's
database notifications) without being taken for data from the printer."""

from __future__ import annotations

import os
import time

import pytest

from printers.transport import SerialTransport


@pytest.fixture
def link(settings, tmp_path):
    settings.DATA_DIR = tmp_path
    master, slave = os.openpty()
    (tmp_path / "printer.tty").symlink_to(os.ttyname(slave))
    transport = SerialTransport.open(str(tmp_path / "printer.tty"), 250000)
    wake_r, wake_w = os.pipe()
    yield master, transport, wake_r, wake_w
    transport.close()
    for fd in (master, slave, wake_r, wake_w):
        os.close(fd)


def test_a_readable_wake_descriptor_ends_the_wait_with_no_data(link):
    _master, transport, wake_r, wake_w = link
    os.write(wake_w, b"x")
    began = time.monotonic()
    assert transport.read(30.0, wake=wake_r) == b""
    assert transport.woken
    assert time.monotonic() - began < 10  # not the 30 s timeout


def test_data_from_the_printer_is_read_and_is_not_a_wake_up(link):
    master, transport, wake_r, _wake_w = link
    os.write(master, b"ok\n")
    assert transport.read(30.0, wake=wake_r) == b"ok\n"
    assert not transport.woken


def test_a_port_without_a_descriptor_still_sees_the_wake_descriptor(
    settings, sim_factory
):
    """rfc2217:// has no descriptor to wait on: the wake descriptor is looked at
    after the port's short wait, so PostgreSQL's notification of an emergency stop
    does not wait for the next poll of the requests (a second while listening)."""
    sim = sim_factory("marlin", "--tcp", "127.0.0.1:0")
    settings.PRINTHOST_PORT_HOSTS = [sim.tcp]
    transport = SerialTransport.open(f"rfc2217://{sim.tcp}", 115200)
    wake_r, wake_w = os.pipe()
    try:
        assert transport.read(0.01, wake=wake_r) == b""
        assert not transport.woken
        os.write(wake_w, b"x")
        transport.read(0.01, wake=wake_r)
        assert transport.woken
    finally:
        transport.close()
        os.close(wake_r)
        os.close(wake_w)
