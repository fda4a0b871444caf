import os

import pytest
from hypothesis import settings

# Keep hypothesis' example database out of the work tree and examples deterministic in CI.
settings.register_profile("roadcollab", database=None, deadline=None, derandomize=True)
settings.load_profile("roadcollab")
os.environ.setdefault("MPLBACKEND", "Agg")


# --- one mixed-speed fleet on the measured road, shared by the network tests -----------------------
# tests/test_network_engine.py and tests/test_network_secure.py used to build the same drives, plan and
# clear in-memory run each; built once per session here (the tests only read them).


@pytest.fixture(scope="session")
def mixed_drives():
    """Four drives at MIXED_SPEEDS over the packaged measured road (fleet rng 2, noise rng 10..13)."""
    from roadcollab.experiments.drives.mixed_fleet import MIXED_SPEEDS, simulate_drive
    from roadcollab.io.profiles import measured_road
    from roadcollab.models.vehicle import FleetSpec, sample_fleet

    road = measured_road(rng=1)
    fleet = sample_fleet(4, FleetSpec(), rng=2)
    return tuple(simulate_drive(road, fleet[j], sp, start=5.0 + 2 * j, rng=10 + j)
                 for j, sp in enumerate(MIXED_SPEEDS))


@pytest.fixture(scope="session")
def mixed_plan(mixed_drives):
    """The road plan of :func:`mixed_drives` (fleet ``t``, the slowest drive's minimum speed)."""
    from roadcollab.network.plan import RoadPlan

    return RoadPlan(fleet_id="t", min_speed=min(float(d.speeds().min()) for d in mixed_drives))


@pytest.fixture(scope="session")
def mixed_clear_run(mixed_drives, mixed_plan):
    """``(store, broker)`` of the clear in-memory run of :func:`mixed_drives` under :func:`mixed_plan`."""
    from roadcollab.network.memory import run_in_memory

    return run_in_memory(list(mixed_drives), mixed_plan)
