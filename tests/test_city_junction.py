"""The simulated city's T-junction and its drives in both directions (fast: matching only, no estimation).

``side`` meets ``main`` at main's measure 300 (not at an end). Drives 8-10 run main 0-300 then turn onto
side; drives 11-12 run side against its measure then main against its measure from the junction to its
start. The estimates on the city (IRI, potholes) are in tests/test_map_e2e.py (slow).
"""


import numpy as np
import pytest

from roadcollab.experiments.drives.city import CITY_ROUTES, simulate_city, write_city
from roadcollab.geo.matching import road_passes
from roadcollab.geo.network import network_from_lonlat
from roadcollab.geo.projection import LocalProjection
from roadcollab.io.drives import load_drives

ORIGIN = LocalProjection(48.137, 11.575)


def _net(roads):
    out = {}
    for rid, pts in roads.items():
        xy = np.array(pts, float)
        lon, lat = ORIGIN.to_lonlat(xy[:, 0], xy[:, 1])
        out[rid] = np.column_stack([lon, lat])
    return network_from_lonlat(out)


def test_a_road_ending_on_another_roads_middle_is_a_t_junction():
    net = _net({"through": [(0, 0), (600, 0)], "side": [(250, 0), (250, -300)]})
    # from through at 100 to side at 50: 150 m to the junction, 50 m down side
    assert net.route_m("through", 100.0, "side", 50.0) == pytest.approx(200.0, abs=1e-3)
    assert net.route_m("side", 50.0, "through", 500.0) == pytest.approx(300.0, abs=1e-3)
    assert [round(m, 3) for m, _ in net.nodes_on["through"]] == [0.0, 250.0, 600.0]
    # 5 m off the through road: no junction (beyond the 1 m tolerance), not connected
    off = _net({"through": [(0, 0), (600, 0)], "side": [(250, -5), (250, -300)]})
    assert off.route_m("through", 100.0, "side", 50.0) == np.inf
    assert len(off.nodes_on["through"]) == 2


@pytest.fixture(scope="module")
def city(tmp_path_factory):
    root = tmp_path_factory.mktemp("tcity")
    files = write_city(root, seed=0)
    truth, _ = simulate_city(seed=0)
    drives = load_drives([str(p) for p in files["drives"]])
    return truth, drives, [road_passes(d, truth.network, sigma_z=5.0) for d in drives]


def _route_of(j):
    routes = [r for r, speeds in CITY_ROUTES for _ in speeds]
    return routes[j]


def test_every_drive_is_matched_to_its_route_lanes_and_never_the_parallel_road(city):
    truth, _drives, passes = city
    assert len(passes) == 12
    for j, ps in enumerate(passes):
        lanes = [(r, 1 if b >= a else -1) for r, a, b in _route_of(j)]
        assert [(p.road_id, p.direction) for p in ps] == lanes, (j + 1, ps)
        if "service" not in truth.roads_driven[j]:
            assert all(p.road_id != "service" for p in ps)


def test_turns_at_the_t_junction_are_cut_at_the_junction(city):
    _truth, _drives, passes = city
    for j in range(7, 10):                        # main forward to 300, then side forward from 0
        (m, s) = passes[j]
        assert m.road_id == "main" and abs(m.u_range[1] - 300.0) <= 0.5, m.u_range
        assert s.road_id == "side" and s.u_range[0] <= 0.5, s.u_range
    for j in (10, 11):                            # side backward to its start, then main backward from 300
        (s, m) = passes[j]
        assert s.road_id == "side" and s.direction == -1 and abs(s.u_range[1] - 400.0) <= 0.5, s.u_range
        assert m.road_id == "main" and m.direction == -1 and abs(m.u_range[0] - 300.0) <= 0.5, m.u_range


def test_lane_coordinates_are_the_true_positions_in_both_directions(city):
    truth, _drives, passes = city
    for j, ps in enumerate(passes):
        true_route = truth.drives[j].positions
        start = 0.0
        for p, (r, a, b) in zip(ps, _route_of(j)):
            length = truth.network.roads[r].length
            u0 = a if b >= a else length - a
            on = (p.drive.positions >= p.u_range[0]) & (p.drive.positions <= p.u_range[1])
            err = p.drive.positions[on] - (u0 + true_route[on] - start)
            # the offset's standard error is about 0.2 m (3 m GPS errors, 100-250 fixes); the shape is the
            # integrated speed column's (3e-5 m off the truth at the varying speed of drive 4)
            assert abs(float(np.mean(err))) < 1.0 and float(np.ptp(err)) < 1e-3, (j + 1, r, np.mean(err))
            start += abs(b - a)


def test_the_truth_has_both_lanes_of_side_and_main(city):
    truth = city[0]
    for lane in (("main", 1), ("main", -1), ("side", 1), ("side", -1), ("cross", 1), ("service", 1)):
        u, h = truth.road_profile(*lane)
        assert u[0] == 0.0 and abs(u[-1] - truth.network.roads[lane[0]].length) < 0.1 and h.shape[1] == 2
    # the two lanes of a road are different wheel tracks
    assert not np.allclose(truth.road_profile("main", 1)[1][:1000], truth.road_profile("main", -1)[1][:1000])
    # a turning drive's route profile is main's forward lane up to the junction (up to a constant)
    route = truth.profiles["main+side"]
    _, h = truth.road_profile("main", 1)
    n = 5000
    assert np.allclose(np.diff(route.elevation[:n], axis=0), np.diff(h[:n], axis=0), atol=1e-12)
