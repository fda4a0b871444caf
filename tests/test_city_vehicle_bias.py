"""Why the T-junction's lanes of the simulated city miss issue 21's 10 % (docs/map.md): each vehicle's bias.

A drive of the city is inverted with the parameters its file carries, the vehicle's own estimate of its
suspension (``FleetSpec().estimate_uncertainty``: 10 % per parameter), while it was simulated with the
true ones. Inverted on its whole route with its true positions (no map matching, no junction, no lane
mapping), drive 10 (main to the T-junction, then side) is about +26 % off the truth's IRI with its file's
parameters and within 1 % with the true ones: the error is the vehicle model's, a gain over the IRI band,
and a lane fused from 2-3 vehicles keeps the mean of their biases. With every drive's true parameters
the whole ``map`` pipeline meets the 10 % on every lane of the city (about 30 s).
"""

import dataclasses
import json

import numpy as np
import pytest

from roadcollab.cli.map import map_command
from roadcollab.experiments.drives.city import simulate_city, write_city
from roadcollab.experiments.drives.distance_maps import band_limit_stretch
from roadcollab.experiments.drives.fleet_estimation import estimate_fleet
from roadcollab.io.drive_params import write_drive_params
from roadcollab.models.iri import iri
from roadcollab.store import RoadStore
from test_map_e2e import _truth_iri

pytestmark = pytest.mark.slow


def _route_iri_error(drive, route_profile) -> float:
    """IRI error of one drive's inversion over its route (40 m off each record end), truth in its band."""
    est = estimate_fleet([drive], spacing=0.05)
    x, h, dx = est.position, est.elevation["inversion"][0], est.spacing
    rx, rh = np.asarray(route_profile.distance), np.asarray(route_profile.elevation)
    true = np.column_stack([np.interp(x, rx, rh[:, c]) for c in range(2)])
    ok = np.isfinite(h[:, 0])
    true[~ok] = np.nan
    true = band_limit_stretch(true, dx, est.band_low_per_m)
    sel = ok & (x > x[ok][0] + 40.0) & (x < x[ok][-1] - 40.0)
    return float((iri(h[sel, 0], dx) + iri(h[sel, 1], dx)) / (iri(true[sel, 0], dx) + iri(true[sel, 1], dx)) - 1)


def test_a_turning_drives_iri_error_is_its_vehicle_parameter_estimate():
    truth, _ = simulate_city(seed=0)
    j = 9                                                # drive 10: main 0-300, then side 0-400 at 14.5 m/s
    drive, vehicle = truth.drives[j], truth.vehicles[j]
    assert truth.routes[j] == (("main", 0.0, 300.0), ("side", 0.0, 400.0))
    assert drive.params == vehicle.estimated_params != vehicle.true_params
    route = truth.profiles["main+side"]
    with_file = _route_iri_error(drive, route)
    with_true = _route_iri_error(dataclasses.replace(drive, params=vehicle.true_params), route)
    assert with_file > 0.15, with_file                   # the e2e run: +23 % to +25 % on side's segments
    assert abs(with_true) < 0.01, with_true


def test_with_the_true_parameters_every_lane_of_the_city_is_within_10_percent(tmp_path):
    """The whole ``map`` pipeline (matching, T-junction cuts, lanes, alignment, fusion) on the city with each
    drive's parameters file holding its vehicle's true parameters: issue 21's 10 % holds on every segment,
    the T-junction's 2-3 vehicle lanes included (measured: at most 0.6 %); with the estimated parameters the
    same lanes miss (tests/test_map_e2e.py::test_every_segment_iri_within_10_percent, a strict xfail)."""
    (tmp_path / "city").mkdir()
    files = write_city(tmp_path / "city", seed=0)
    truth = simulate_city(seed=0)[0]
    for j, (drive, vehicle) in enumerate(zip(truth.drives, truth.vehicles), start=1):
        constant = drive.speed_source == "parameters"
        write_drive_params(tmp_path / "city" / f"drive{j}.toml", speed=drive.speed if constant else None,
                           params=vehicle.true_params)
    map_command([str(p) for p in files["drives"]], tmp_path / "out", store_url=tmp_path / "roads.sqlite",
                command="test", network_path=files["network"], bootstrap=0, seed=0)
    bands = json.loads((tmp_path / "out" / "config.json").read_text())["config"]["band_low_per_m"]
    with RoadStore.open(tmp_path / "roads.sqlite") as store:
        segs = store.segments()
    errors = {(s.road_id, s.direction, s.from_m): s.iri_m_per_km / _truth_iri(
        truth, s.road_id, bands[f"{s.road_id}:{s.direction:+d}"], s.from_m, s.to_m, s.profile_spacing_m,
        s.direction) - 1 for s in segs}
    assert len(errors) == 21 and {k[:2] for k in errors} >= {("side", 1), ("side", -1), ("main", -1)}
    assert max(abs(v) for v in errors.values()) <= 0.02, errors
