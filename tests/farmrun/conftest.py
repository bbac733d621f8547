"""The farm tests' farm: `tests.farmrig.Farm` at the size `make test` affords.

3 worker hosts, 6 printers (two a host), 10 jobs of real slicer files (about 1,600
lines each) and one generated wide part. Motion timing is on at `--time-scale
0.03`: the flat box's 5 minutes take 9 s, about 170 lines a second per printer
(a fast printer on curves), so a run lasts about a minute, and six printers,
their workers, the simulators, PostgreSQL and the control plane use about 0.8 of
the two cores (measured): the machine keeps up. (Jobs then take 4-13 % longer
than alone: bench/farm.py measures that at its own speed.)

The farm tests: test_farm_run.py (no faults), test_farm_database_away.py,
test_farm_redis_away.py, test_farm_host_killed.py; a dispatcher killed inside its
claim is tests/farm/test_dispatcher_postgres.py (real PostgreSQL, SIGKILL).
bench/farm.py runs the same tests at full size.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from tests.farmrig.rig import Farm, FarmConfig

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from pathlib import Path

#: The farm of `make test` (bench/farm.py runs the full size).
SMALL = FarmConfig(hosts=3, printers=6, jobs=10, time_scale=0.03, lease_seconds=3.0)


@pytest.fixture
def make_farm(tmp_path: Path) -> Iterator[Callable[..., Farm]]:
    """Set up (not start) a farm in this test's folder; it is stopped afterwards."""
    farms: list[Farm] = []

    def factory(**changes: object) -> Farm:
        config = FarmConfig(**{**SMALL.__dict__, **changes})
        farm = Farm(tmp_path / f"farm{len(farms)}", config)
        farms.append(farm)
        farm.setup()
        return farm

    yield factory
    for farm in farms:
        farm.close()
