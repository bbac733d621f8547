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
