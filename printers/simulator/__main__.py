"""`python -m printers.simulator marlin|grbl ...`: run a firmware simulator."""

from __future__ import annotations

import sys

from printers.simulator.cli import main

if __name__ == "__main__":
    sys.exit(main())
