"""Roads on a map (issue 21): GPS columns, networks, map matching, linear referencing, projection."""

import json
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roadcollab import ParameterError
from roadcollab.geo.matching import lonlat_at, match_fixes, road_passes
from roadcollab.geo.network import network_from_lonlat, read_network, track_road
from roadcollab.geo.projection import LocalProjection, geodesic_m
from roadcollab.geo.segments import IN_PER_MI_PER_M_PER_KM, segment_bounds
from roadcollab.io.drive_params import write_drive_params
from roadcollab.io.drives import load_drive
from roadcollab.io.gps import read_gps_log, write_gps_drive_csv
from roadcollab.models.vehicle import HalfCarParameters

PARAMS = HalfCarParameters(700.0, 500.0, 0.7, 0.8, 20000.0, 1500.0)
ORIGIN = (48.137, 11.575)


def _lonlat(proj, xy):
    xy = np.asarray(xy, float)
    lon, lat = proj.to_lonlat(xy[:, 0], xy[:, 1])
    return np.column_stack([lon, lat])


def _parallel_network():
    """Two straight roads 10 m apart (not connected) and a third meeting the first at (500, 0)."""
    proj = LocalProjection(*ORIGIN)
    return network_from_lonlat({"south": _lonlat(proj, [(0, 0), (500, 0)]),
                                "north": _lonlat(proj, [(0, 10), (500, 10)]),
                                "east": _lonlat(proj, [(500, 0), (500, -300)])}), proj


# --- projection ----------------------------------------------------------------------------------

def test_geodesic_reference_values():
    # WGS 84 meridian arc from 0 to 1 degree latitude: 110,574.4 m (e.g. the NGA/NIMA TR8350.2 tables).
    assert abs(geodesic_m(0.0, 0.0, 0.0, 1.0) - 110574.4) < 0.5
    # One degree of longitude on the equator: a * pi / 180 = 111,319.49 m (a = 6,378,137 m).
    assert abs(geodesic_m(0.0, 0.0, 1.0, 0.0) - 6378137.0 * np.pi / 180) < 0.01


def test_local_projection_is_metric_near_its_centre():
    proj = LocalProjection(*ORIGIN)
    rng = np.random.default_rng(0)
    xy = rng.uniform(-3000, 3000, (50, 2))
    lon, lat = proj.to_lonlat(xy[:, 0], xy[:, 1])
    back = np.column_stack(proj.to_xy(lon, lat))
    assert np.max(np.abs(back - xy)) < 1e-6
    d_plane = np.hypot(*(xy[1:] - xy[:-1]).T)
    d_geo = geodesic_m(lon[1:], lat[1:], lon[:-1], lat[:-1])
    assert np.max(np.abs(d_plane / d_geo - 1)) < 2e-7        # scale error x^2 / 2R^2 < 1.2e-7 at 3 km


# --- GPS columns -----------------------------------------------------------------------------------

def _gps_drive(tmp_path, name="g.csv", n=400, every=20):
    t = np.arange(n) / 100.0
    accel = np.column_stack([np.sin(2 * np.pi * 2 * t), np.cos(2 * np.pi * 3 * t)])
    lat, lon = np.full(n, np.nan), np.full(n, np.nan)
    lat[::every], lon[::every] = 48.1 + 1e-5 * t[::every], 11.5 + 2e-5 * t[::every]
    path = write_gps_drive_csv(tmp_path / name, t, accel, lat, lon, column="speed_mps", values=np.full(n, 12.0))
    write_drive_params(path.with_suffix(".toml"), speed=None, params=PARAMS)
    return path, t, accel, lat, lon


def test_gps_columns_are_read_with_the_drive(tmp_path):
    path, t, accel, lat, lon = _gps_drive(tmp_path)
    d = load_drive(path)
    assert d.gps is not None and d.gps.n_fixes == 20 and abs(d.gps.rate_hz - 5.0) < 1e-9
    assert np.array_equal(d.gps.time, t[::20]) and np.array_equal(d.gps.lat, lat[::20])
    assert np.array_equal(d.gps.lon, lon[::20])
    assert np.array_equal(d.accel, accel) and np.allclose(d.positions, 12.0 * t)


def test_drive_without_gps_has_none(tmp_path):
    from roadcollab.io.drives import write_drive_csv
    t = np.arange(200) / 100.0
    write_drive_csv(tmp_path / "a.csv", t, np.zeros((200, 2)))
    write_drive_params(tmp_path / "a.toml", speed=10.0, params=PARAMS)
    assert load_drive(tmp_path / "a.csv").gps is None


def test_bad_gps_cells_name_the_line(tmp_path):
    path, *_ = _gps_drive(tmp_path)
    lines = path.read_text().splitlines()
    bad = lines[:]
    bad[21] = bad[21].rsplit(",", 1)[0] + ","                           # line 22: lat without lon
    path.write_text("\n".join(bad) + "\n")
    with pytest.raises(ParameterError, match=re.escape(f"{path} line 22: expected both lat_deg and lon_deg or "
                                                       "neither")):
        read_gps_log(path)
    bad = lines[:]
    bad[41] = ",".join(bad[41].split(",")[:4] + ["95.0", "11.5"])        # line 42: latitude out of range
    path.write_text("\n".join(bad) + "\n")
    with pytest.raises(ParameterError, match=re.escape(f"{path} line 42: column 5 (lat_deg): expected degrees "
                                                       "within +-90")):
        read_gps_log(path)
    bad = lines[:]
    bad[9] = "0.08,abc,0.1,12.0,,"                                      # the drive log's own check, same line
    path.write_text("\n".join(bad) + "\n")
    with pytest.raises(ParameterError, match="^" + re.escape(f"{path} line 10: column 2 (accel_left)")):
        read_gps_log(path)


def test_gps_columns_must_come_last(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text("time_s,lat_deg,lon_deg,accel_left,accel_right\n")
    with pytest.raises(ParameterError, match="expected the GPS columns last"):
        read_gps_log(p)


# --- network and segments ----------------------------------------------------------------------------

def test_network_file_errors(tmp_path):
    p = tmp_path / "n.geojson"
    line = {"type": "LineString", "coordinates": [[11.5, 48.1], [11.51, 48.1]]}
    p.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"name": "x"}, "geometry": line}]}))
    with pytest.raises(ParameterError, match=re.escape(f"{p}: features[0].properties.road_id: expected a non-empty")):
        read_network(p)
    feat = {"type": "Feature", "properties": {"road_id": "a"}, "geometry": line}
    p.write_text(json.dumps({"type": "FeatureCollection", "features": [feat, feat]}))
    with pytest.raises(ParameterError, match="'a' is used twice"):
        read_network(p)
    swapped = {"type": "LineString", "coordinates": [[48.1, 100.5], [48.1, 100.51]]}      # lat, lon: |lat| > 90
    p.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"road_id": 1}, "geometry": swapped}]}))
    with pytest.raises(ParameterError, match="RFC 7946 order: longitude first"):
        read_network(p)
    p.write_text("{not json")
    with pytest.raises(ParameterError, match="expected a GeoJSON"):
        read_network(p)


def test_route_distance_through_the_junction():
    net, _ = _parallel_network()
    south, east = net.roads["south"].length, net.roads["east"].length
    assert abs(south - 500.0) < 1e-6 and abs(east - 300.0) < 1e-6
    assert abs(net.route_m("south", 450.0, "east", 20.0) - 70.0) < 1e-6          # 50 m to the junction, 20 beyond
    assert net.route_m("south", 450.0, "north", 450.0) == np.inf                  # not connected
    assert net.route_m("south", 100.0, "south", 40.0) == 60.0


@settings(max_examples=60, deadline=None)
@given(st.floats(1.0, 5000.0), st.floats(1.0, 500.0))
def test_segment_bounds_cover_the_road(length, seg):
    b = segment_bounds(length, seg)
    assert b[0][0] == 0.0 and b[-1][1] == length
    assert all(a1 == b0 for (_, a1), (b0, _) in zip(b[:-1], b[1:]))
    lengths = [y - x for x, y in b]
    assert all(x > 0 for x in lengths)
    assert all(abs(x - seg) < 1e-6 for x in lengths[:-1])                        # fixed, except the last
    assert len(b) == 1 or 0.5 * seg - 1e-6 <= lengths[-1] < 1.5 * seg + 1e-6


def test_iri_unit():
    assert IN_PER_MI_PER_M_PER_KM == pytest.approx(63360 / 1000)                  # 1 mi = 63,360 in


# --- map matching --------------------------------------------------------------------------------------

def test_parallel_road_is_not_chosen_under_3m_noise():
    net, proj = _parallel_network()
    rng = np.random.default_rng(3)
    x = np.arange(5.0, 495.0, 3.0)
    for road, y0 in (("south", 0.0), ("north", 10.0)):
        xy = np.column_stack([x, np.full_like(x, y0)]) + rng.normal(0, 3.0, (x.size, 2))
        lon, lat = proj.to_lonlat(xy[:, 0], xy[:, 1])
        m = match_fixes(net, lon, lat, sigma_z=5.0)
        assert set(m.road_id) == {road}
        # Per fix the nearest road is wrong for about P(noise > 5 m) = 4.8 %: the HMM fixes them all.
        nearest = np.where(np.abs(xy[:, 1] - 0.0) < np.abs(xy[:, 1] - 10.0), "south", "north")
        assert np.any(nearest != road)


def test_route_through_the_junction_is_followed():
    net, proj = _parallel_network()
    pts = [(x, 0.0) for x in np.arange(300.0, 500.0, 4.0)] + [(500.0, -y) for y in np.arange(4.0, 200.0, 4.0)]
    xy = np.array(pts) + np.random.default_rng(1).normal(0, 3.0, (len(pts), 2))
    lon, lat = proj.to_lonlat(xy[:, 0], xy[:, 1])
    m = match_fixes(net, lon, lat)
    k = 50                                         # fixes 0..49 on south, the rest on east
    assert np.sum(m.road_id[:k - 2] != "south") == 0 and np.sum(m.road_id[k + 2:] != "east") == 0


def _drive_on(tmp_path, net, proj, *, backward: bool, sigma: float, rng):
    n, fs, v = 3000, 100.0, 12.0
    t = np.arange(n) / fs
    s = 20.0 + v * t                                             # true measure on "south", forward
    if backward:
        s = 480.0 - v * t
    lat, lon = np.full(n, np.nan), np.full(n, np.nan)
    k = np.arange(0, n, 20)
    xy = np.column_stack([s[k], np.zeros(k.size)]) + rng.normal(0, sigma, (k.size, 2))
    lon[k], lat[k] = proj.to_lonlat(xy[:, 0], xy[:, 1])
    accel = rng.normal(0, 0.1, (n, 2))
    path = write_gps_drive_csv(tmp_path / f"d{int(backward)}.csv", t, accel, lat, lon)
    write_drive_params(path.with_suffix(".toml"), speed=v, params=PARAMS, start_m=1234.0)
    return load_drive(path), s


@pytest.mark.parametrize("backward", [False, True])
def test_road_positions_from_fixes_and_odometer(tmp_path, backward):
    net, proj = _parallel_network()
    d, s = _drive_on(tmp_path, net, proj, backward=backward, sigma=0.0, rng=np.random.default_rng(0))
    (p,) = road_passes(d, net)
    assert p.road_id == "south" and p.direction == (-1 if backward else 1)
    u_true = (500.0 - s) if backward else s                       # lane coordinate
    assert np.max(np.abs(p.drive.positions - u_true)) < 1e-6      # noise-free fixes: exact (the odometer is exact)
    d3, s3 = _drive_on(tmp_path, net, proj, backward=backward, sigma=3.0, rng=np.random.default_rng(5))
    (p3,) = road_passes(d3, net)
    err = float(np.mean(p3.drive.positions - ((500.0 - s3) if backward else s3)))
    # 150 fixes of 3 m: standard error 0.24 m; 4 standard errors
    assert abs(err) < 4 * 3.0 / np.sqrt(150) and abs(p3.offset_std - 3.0 / np.sqrt(150)) < 0.1


def test_track_road_without_network():
    proj = LocalProjection(*ORIGIN)
    x = np.arange(0.0, 400.0, 2.0)
    xy = np.column_stack([x, 0.02 * x]) + np.random.default_rng(2).normal(0, 3.0, (x.size, 2))
    lon, lat = proj.to_lonlat(xy[:, 0], xy[:, 1])
    net = network_from_lonlat({"mine": track_road("mine", lon, lat)})
    length = net.roads["mine"].length
    assert abs(length - np.hypot(400, 8)) < 0.05 * 400        # the smoothed track is nearly the road's length
    lo, la = lonlat_at(net, "mine", [0.0, length])
    assert lo.shape == (2,)


@pytest.mark.parametrize("sigma", [0.0, 3.0])
def test_a_drive_that_passes_the_same_road_twice(tmp_path, sigma):
    """South forward to the junction, east out and back (a U-turn), south backward: four passes, each on
    its own samples with its own direction; noise-free fixes give the exact lane coordinate."""
    net, proj = _parallel_network()
    fs, v = 100.0, 12.0
    legs = [("south", 20.0, 500.0), ("east", 0.0, 150.0), ("east", 150.0, 0.0), ("south", 500.0, 100.0)]
    xy, truth = [], []
    for road, a, b in legs:
        n = int(abs(b - a) / v * fs)
        m = a + np.sign(b - a) * v * np.arange(n) / fs
        xy.append(np.column_stack([m, np.zeros(n)]) if road == "south" else np.column_stack([np.full(n, 500.0), -m]))
        truth.append(m)
    xy, n = np.vstack(xy), sum(len(m) for m in truth)
    t = np.arange(n) / fs
    lat, lon = np.full(n, np.nan), np.full(n, np.nan)
    k = np.arange(0, n, 20)
    noisy = xy[k] + np.random.default_rng(3).normal(0, sigma, (k.size, 2))
    lon[k], lat[k] = proj.to_lonlat(noisy[:, 0], noisy[:, 1])
    path = write_gps_drive_csv(tmp_path / "twice.csv", t, np.random.default_rng(0).normal(0, 0.1, (n, 2)), lat, lon)
    write_drive_params(path.with_suffix(".toml"), speed=v, params=PARAMS, start_m=0.0)
    passes = road_passes(load_drive(path), net)
    assert [(p.road_id, p.direction) for p in passes] == [("south", 1), ("east", 1), ("east", -1), ("south", -1)]
    if sigma > 0:                                   # 3 m noise: the passes are found; positions are tested above
        return
    start = np.cumsum([0] + [len(m) for m in truth])
    for p, (road, a, b), m, i0 in zip(passes, legs, truth, start):
        length = net.roads[road].length
        u_true = m if p.direction > 0 else length - m
        assert np.max(np.abs(p.drive.positions[i0:i0 + len(m)] - u_true)) < 1e-6
        lo, hi = sorted((a, b))
        expect = (lo, hi) if p.direction > 0 else (length - hi, length - lo)
        gap = v * 20 / fs                           # odometer between two fixes: where the turn is known
        assert abs(p.u_range[0] - expect[0]) <= gap and abs(p.u_range[1] - expect[1]) <= gap
