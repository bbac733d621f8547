"""The Marlin model speaking other firmware's line errors; resets, echoes, line noise."""

from __future__ import annotations

import pytest

from printers.simulator.faults import FaultConfig, Faults
from tests.simulator.test_marlin_firmware import Bench


def plain(dialect: str, **options: object) -> Bench:
    return Bench(advanced_ok=False, dialect=dialect, **options)


@pytest.mark.parametrize(
    ("dialect", "bad", "replies"),
    [
        ("marlin", "N2 G1 X2*0", [
            "Error:checksum mismatch, Last Line: 1", "Resend: 2", "ok"]),
        ("prusa", "G1 X2*7", ["Error:No Line Number with checksum, Last Line: 1"]),
        ("marlin", "X2*7", ["Error:No Line Number with checksum, Last Line: 1"]),
        ("repetier", "N3 G1 X2*0", [
            "Error:expected line 2 got 3", "Resend:2", "ok"]),
        ("repetier", "N2 G1 X2*0", ["Error:Wrong checksum", "Resend:2", "ok"]),
        ("repetier", "N2 G1 X2", ["Error:Missing checksum", "Resend:2", "ok"]),
        ("repetier", "N1 G1 X1*0", ["skip 1", "ok"]),
        ("smoothieware", "N2 G1 X2*0", ["rs N2"]),
        ("smoothieware", "N5 G1 X2*0", ["rs N2"]),
        ("reprapfirmware", "N2 G1 X2*0", []),
    ],
)  # fmt: skip
def test_each_dialect_words_a_bad_line_its_own_way(
    dialect: str, bad: str, replies: list[str]
) -> None:
    bench = plain(dialect)
    bench.framed(1, "G1 X1")
    assert bench.send(bad + "\n") == replies


def test_repetier_acknowledges_with_the_line_number() -> None:
    assert plain("repetier").framed(1, "G1 X1") == ["ok 1"]


def test_reprapfirmware_does_not_check_the_sequence() -> None:
    bench = plain("reprapfirmware")
    assert bench.framed(7, "G1 X1") == ["ok"]
    assert bench.executed == ["G1 X1"]


def test_ok_before_resend_switch_swaps_the_order() -> None:
    bench = plain("marlin", ok_before_resend=True)
    assert bench.send("N1 G1 X1*0\n") == [
        "Error:checksum mismatch, Last Line: 0",
        "ok",
        "Resend: 1",
    ]


@pytest.mark.parametrize(("style", "echo"), [("echo", "echo:G1 X1"), ("raw", "G1 X1")])
def test_echo_lines_prints_each_line_back(style: str, echo: str) -> None:
    assert plain("marlin", echo_lines=style).send("G1 X1\n") == [echo, "ok"]


@pytest.mark.parametrize(
    ("banner", "first"),
    [("start", b"start\n"), ("none", b""), ("noise", b"\xfe\xff\x00start\n")],
)
def test_reset_fault_banners(banner: str, first: bytes) -> None:
    bench = Bench(faults=Faults(FaultConfig(reset_after=1, reset_banner=banner)))
    bench.fw.receive(b"G1 X1\n", 0.0)
    bench.fw.step(0.0)
    ok, _, rest = bench.fw.data_to_send().partition(b"\n")
    assert ok == b"ok P15 B3"
    assert rest.startswith(first) and (banner != "none" or rest == b"")


def test_reset_banner_must_be_known() -> None:
    with pytest.raises(ValueError, match="reset_banner"):
        FaultConfig(reset_banner="loud").validate()


def test_line_noise_garbles_about_the_share_of_bytes() -> None:
    faults = Faults(FaultConfig(seed=3))
    data = b"N12 G1 X5.000 Y7.000*34\n" * 1000
    garbled = faults.garble(data, 0.01)
    assert 150 < faults.garbled < 330
    assert garbled != data
    assert faults.garble(data, 0.0) == data


def test_reprapfirmware_names_itself_in_m115() -> None:
    lines = plain("reprapfirmware").send("M115\n")
    assert lines[0].startswith("FIRMWARE_NAME: RepRapFirmware")
    assert lines[-1] == "ok"


def test_line_noise_one_per_line_hits_each_line_at_most_once() -> None:
    faults = Faults(FaultConfig(seed=5))
    data = b"N12 G1 X5.000 Y7.000*34\n" * 200
    garbled = faults.garble(data, 0.5, one_per_line=True)
    damaged = [line for line in garbled.split(b"\n") if len(line) > 1]
    assert faults.garbled <= 200 + 50  # a hit may also make or take a line end
    assert len(damaged) > 100
