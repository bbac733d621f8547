"""Firmware simulators (Marlin, GRBL): sans-IO models plus a pty/TCP runner for tests and benchmarks."""

from __future__ import annotations

from printers.simulator.faults import FaultConfig, Faults
from printers.simulator.grbl import GrblFirmware
from printers.simulator.link import Wire
from printers.simulator.marlin import MarlinFirmware

__all__ = ["FaultConfig", "Faults", "GrblFirmware", "MarlinFirmware", "Wire"]
