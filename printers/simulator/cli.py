"""Command line of the firmware simulators: `python -m printers.simulator marlin --link ./printer0`."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from printers.simulator._marlin_dialect import DIALECTS
from printers.simulator._record import state_text
from printers.simulator.faults import RESET_BANNERS, FaultConfig, Faults
from printers.simulator.grbl import GrblFirmware
from printers.simulator.marlin import MarlinFirmware
from printers.simulator.runner import (
    Recorder,
    RunnerConfig,
    SetupError,
    Simulator,
    write_ready_line,
)

if TYPE_CHECKING:
    from collections.abc import Callable

__all__ = ["build_parser", "main"]

_DESCRIPTION = """\
Simulate a Marlin or GRBL controller on a pty (and/or TCP), paced at the
serial baud rate in both directions. Prints one JSON line when ready:
{"ready": true, "pty": ..., "tcp": ..., "pid": ...}.
Control socket commands: reset, close, reopen, busy <seconds>,
corrupt <share>, drop-ok <every_n>, halt, stats, flush (the record written
out now), click, action <text>, say <text>,
sd (the card as JSON), sd-stop (the display stops the card's print).
"""


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog or "python -m printers.simulator",
        description=_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("firmware", choices=("marlin", "grbl"))
    ports = parser.add_argument_group("ports")
    ports.add_argument("--link", type=Path, help="symlink to create for the pty")
    ports.add_argument(
        "--tcp", metavar="HOST:PORT", help="also listen on TCP (port 0 = any)"
    )
    ports.add_argument("--baud", type=int, default=115200, help="0 = unthrottled")
    ports.add_argument("--latency-ms", type=float, default=0.0, help="each direction")
    ports.add_argument("--record", type=Path, help="append executed commands here")
    ports.add_argument(
        "--record-state",
        action="store_true",
        help="with each recorded command, a tab, `@` and a state: for Marlin the "
        "position (X Y Z E) it found; for GRBL the work position and `$G` modes it "
        "left (GRBL records a line once it ran)",
    )
    ports.add_argument("--control", type=Path, help="Unix socket for control commands")
    machine = parser.add_argument_group("firmware")
    machine.add_argument(
        "--rx-buffer", type=int, help="UART ring bytes (128; grblHAL 1024)"
    )
    machine.add_argument(
        "--variant",
        choices=("grbl", "grblhal"),
        default="grbl",
        help="GRBL only: grbl 1.1h or grblHAL (banner, $I, RX buffer)",
    )
    machine.add_argument("--bufsize", type=int, default=4, help="Marlin command slots")
    machine.add_argument("--planner", type=int, default=16, help="planner blocks")
    machine.add_argument("--time-scale", type=float, default=1.0, help="0 = instant")
    machine.add_argument(
        "--instant-waits", action="store_true",
        help="Marlin: heat-ups and homing take no time (moves keep the time scale)",
    )  # fmt: skip
    machine.add_argument(
        "--advanced-ok", action=argparse.BooleanOptionalAction, default=True
    )
    machine.add_argument(
        "--emergency-parser", action=argparse.BooleanOptionalAction, default=True
    )
    machine.add_argument(
        "--keepalive", type=float, default=2.0, help="seconds; 0 = off"
    )
    machine.add_argument(
        "--host-prompts", action=argparse.BooleanOptionalAction, default=True,
        help="Marlin: M600 sends //action:paused and a prompt (HOST_PROMPT_SUPPORT)",
    )  # fmt: skip
    machine.add_argument(
        "--dialect", choices=tuple(DIALECTS), default="marlin",
        help="Marlin: wording and order of line errors of this firmware",
    )  # fmt: skip
    machine.add_argument(
        "--echo-lines", choices=("echo", "raw"),
        help="Marlin: print each received line back (echo:<line>, or as is)",
    )  # fmt: skip
    machine.add_argument(
        "--sd-card", action="store_true",
        help="Marlin: SDSUPPORT with an empty card in memory",
    )  # fmt: skip
    machine.add_argument(
        "--sd-dir", type=Path,
        help="Marlin: SDSUPPORT; the card is this folder (8.3 upper-case names)",
    )  # fmt: skip
    machine.add_argument(
        "--ok-before-resend", action="store_true",
        help="Marlin: send a rejected line's ok before its Resend",
    )  # fmt: skip
    machine.add_argument(
        "--cancel-objects", action="store_true",
        help="Marlin: CANCEL_OBJECTS (M486), reported as Cap:CANCEL_OBJECTS:1",
    )  # fmt: skip
    faults = parser.add_argument_group("faults")
    faults.add_argument("--corrupt", type=float, default=0.0, metavar="SHARE")
    faults.add_argument("--seed", type=int)
    faults.add_argument(
        "--noise-to-firmware", type=float, default=0.0, metavar="SHARE",
        help="share of bytes garbled on the wire towards the firmware",
    )  # fmt: skip
    faults.add_argument(
        "--noise-to-host", type=float, default=0.0, metavar="SHARE",
        help="share of bytes garbled on the wire towards the host",
    )  # fmt: skip
    faults.add_argument("--drop-ok-every", type=int, default=0, metavar="N")
    faults.add_argument(
        "--drop-ok-share", type=float, default=0.0, metavar="SHARE",
        help="lose this share of oks at random (with --seed: repeatable)",
    )  # fmt: skip
    faults.add_argument("--reset-after", type=int, default=0, metavar="N")
    faults.add_argument(
        "--reset-banner", choices=RESET_BANNERS, default="start",
        help="what the reset-after reset prints (none: a silent reset)",
    )  # fmt: skip
    faults.add_argument("--busy-after", type=int, default=0, metavar="N")
    faults.add_argument("--busy-seconds", type=float, default=0.0, metavar="S")
    faults.add_argument("--close-after", type=int, default=0, metavar="N")
    faults.add_argument("--reopen-after", type=float, metavar="S")
    return parser


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Run a simulator until SIGTERM/SIGINT; 2 for bad arguments or ports."""
    parser = build_parser(prog)
    try:
        args = parser.parse_args(argv)
        config = _runner_config(parser, args)
        faults = Faults(_fault_config(parser, args))
    except SystemExit as stop:
        return stop.code if isinstance(stop.code, int) else 2
    outside = _outside_data_dir("--record", args.record) or _outside_data_dir(
        "--sd-dir", args.sd_dir
    )
    if outside:
        return _fail(parser, outside)
    try:
        recorder = Recorder(args.record) if args.record else None
    except OSError as error:
        return _fail(parser, f"--record {args.record}: {error.strerror}")
    firmware = _firmware(args, faults, recorder)
    simulator = Simulator(firmware, config, faults, recorder)
    try:
        info = simulator.start()
    except SetupError as error:
        return _fail(parser, str(error))
    try:
        write_ready_line(info)
        simulator.run()
    finally:
        simulator.close()
    return 0


def _outside_data_dir(option: str, path: Path | None) -> str:
    """Under printhost (PRINTHOST_DATA_DIR set, as runhost's children have it) the
    record file and the card's folder must stay in the data directory; "" when they
    do or are not asked for."""
    data_dir = os.environ.get("PRINTHOST_DATA_DIR", "")
    if path is None or not data_dir:
        return ""
    root = Path(data_dir).resolve()
    target = path.resolve()
    if target.is_relative_to(root) and target != root:
        return ""
    return f"{option} {path}: must be inside the data directory {root}"


def _fail(parser: argparse.ArgumentParser, message: str) -> int:
    sys.stderr.write(f"{parser.prog}: error: {message}\n")
    return 2


def _runner_config(
    parser: argparse.ArgumentParser, args: argparse.Namespace
) -> RunnerConfig:
    if args.link is None and args.tcp is None:
        parser.error("give --link PATH and/or --tcp HOST:PORT")
    if args.baud < 0 or args.latency_ms < 0 or args.time_scale < 0:
        parser.error("--baud, --latency-ms and --time-scale must not be negative")
    if args.variant != "grbl" and args.firmware != "grbl":
        parser.error("--variant is for grbl only")
    if min(args.rx_buffer or 1, args.bufsize, args.planner) < 1:
        parser.error("--rx-buffer, --bufsize and --planner must be at least 1")
    if args.sd_dir is not None and not args.sd_dir.is_dir():
        parser.error(f"--sd-dir {args.sd_dir}: no such folder")
    if (args.sd_dir or args.sd_card) and args.firmware != "marlin":
        parser.error("--sd-card and --sd-dir are for marlin only")
    if args.link is not None and not args.link.parent.is_dir():
        parser.error(f"--link {args.link}: folder {args.link.parent} does not exist")
    return RunnerConfig(
        link=args.link,
        tcp=_tcp_address(parser, args.tcp) if args.tcp else None,
        baud=args.baud or None,
        latency=args.latency_ms / 1000.0,
        record=args.record,
        control=args.control,
    )


def _tcp_address(parser: argparse.ArgumentParser, text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or int(port) > 65535:
        parser.error(f"--tcp {text!r}: expected HOST:PORT, for example 127.0.0.1:0")
    return host.strip("[]"), int(port)


def _fault_config(
    parser: argparse.ArgumentParser, args: argparse.Namespace
) -> FaultConfig:
    config = FaultConfig(
        corrupt=args.corrupt,
        seed=args.seed,
        noise_to_firmware=args.noise_to_firmware,
        noise_to_host=args.noise_to_host,
        drop_ok_every=args.drop_ok_every,
        drop_ok_share=args.drop_ok_share,
        reset_after=args.reset_after,
        reset_banner=args.reset_banner,
        busy_after=args.busy_after,
        busy_seconds=args.busy_seconds,
        close_after=args.close_after,
        reopen_after=args.reopen_after,
    )
    try:
        config.validate()
    except ValueError as error:
        parser.error(str(error))
    return config


def _firmware(
    args: argparse.Namespace, faults: Faults, recorder: Recorder | None
) -> MarlinFirmware | GrblFirmware:
    on_execute = recorder.add if recorder is not None else None
    if recorder is not None and args.record_state:
        built: list[MarlinFirmware | GrblFirmware] = []

        def record_with_state(text: str) -> None:
            recorder.add(f"{text}\t@ {state_text(built[0])}")

        built.append(_firmware_with(args, faults, record_with_state))
        return built[0]
    return _firmware_with(args, faults, on_execute)


def _firmware_with(
    args: argparse.Namespace,
    faults: Faults,
    on_execute: Callable[[str], None] | None,
) -> MarlinFirmware | GrblFirmware:
    now = time.monotonic()
    if args.firmware == "grbl":
        return GrblFirmware(
            rx_buffer=args.rx_buffer,
            planner=args.planner,
            variant=args.variant,
            time_scale=args.time_scale,
            faults=faults,
            on_execute=on_execute,
            now=now,
        )
    return MarlinFirmware(
        rx_buffer=args.rx_buffer or 128,
        bufsize=args.bufsize,
        planner=args.planner,
        time_scale=args.time_scale,
        instant_waits=args.instant_waits,
        advanced_ok=args.advanced_ok,
        emergency_parser=args.emergency_parser,
        keepalive=args.keepalive,
        host_prompts=args.host_prompts,
        dialect=args.dialect,
        ok_before_resend=args.ok_before_resend,
        echo_lines=args.echo_lines or "",
        sd_card=args.sd_card,
        sd_dir=args.sd_dir,
        faults=faults,
        on_execute=on_execute,
        now=now,
        cancel_objects=args.cancel_objects,
    )
