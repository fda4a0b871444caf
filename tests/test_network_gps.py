"""GPS drives through the networked fleet onto the map (network/fleetroad.py, RoadSync's geometry).

A small network from ``simulate-drives --gps --network``: ``main`` (350 m, with a bend) and ``side``, a
road 10 m beside it; three drives on each. The fleet surveys ``main``. Compared with what
``roadcollab map`` writes for the same drives: the segment geometries (the same function on the same
network file: equal to 1e-9 degrees, about 0.1 mm) and the anomalies (within 2 m, great-circle); and with
the truth (IRI within 10 %, potholes within 2 m).
"""

import json

import numpy as np
import pytest

from roadcollab.cli.main import main
from roadcollab.errors import ParameterError
from roadcollab.geo.projection import LocalProjection, geodesic_m
from roadcollab.io.drive_clean import clean_drive
from roadcollab.io.drives import load_drives
from roadcollab.network.fleetroad import ROAD_FILE, FleetRoad, file_sha256
from roadcollab.network.fleetdir import load_plan
from roadcollab.network.livemap import _content
from roadcollab.network.memory import run_in_memory
from roadcollab.network.plan import RoadPlan
from roadcollab.network.roadsync import RoadSync
from roadcollab.network.store import ServiceStore
from roadcollab.store import RoadStore

ORIGIN = LocalProjection(48.137, 11.575)


def _line(pts):
    xy = np.array(pts, float)
    lon, lat = ORIGIN.to_lonlat(xy[:, 0], xy[:, 1])
    return [[float(a), float(b)] for a, b in zip(lon, lat)]


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """``(folder, main's drive paths, side's drive paths, network path)`` of the simulated drives."""
    root = tmp_path_factory.mktemp("gpsnet")
    net = root / "net.geojson"
    net.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"road_id": "main"},
         "geometry": {"type": "LineString", "coordinates": _line([(0, 0), (200, 0), (350, 20)])}},
        {"type": "Feature", "properties": {"road_id": "side"},
         "geometry": {"type": "LineString", "coordinates": _line([(0, 10), (350, 10)])}}]}))
    assert main(["simulate-drives", "--gps", "--network", str(net), "--vehicles", "3", "--out", str(root / "sim")]) == 0
    paths = [str(root / "sim" / f"drive{j}.csv") for j in range(1, 7)]
    return root, paths[:3], paths[3:], root / "sim" / "network.geojson"


def _network_run(root, paths, network, name):
    """The fleet on ``main`` in memory with a RoadSync: ``(road store path, placed drives' hellos)``."""
    from roadcollab.geo.network import read_network

    road = FleetRoad(read_network(network), "main")
    drives = [clean_drive(d)[0] for d in load_drives(paths)]
    vmin = min(float(road.place(d)[0].speeds().min()) for d in drives)
    plan = RoadPlan(fleet_id="t", min_speed=vmin, road_id="main", road_sha256=file_sha256(network))
    svc = ServiceStore(root / f"{name}-s.sqlite", plan)
    url = root / f"{name}-roads.sqlite"
    with RoadStore.open(url) as roads:
        sync = RoadSync(roads, svc, road=road)
        run_in_memory(drives, plan, store=svc, on_fused=sync, road=road)
        sync.flush()
    hellos = dict(svc.vehicles())
    svc.close()
    return url, hellos


@pytest.fixture(scope="module")
def clear_run(sim):
    """The clear networked run of the three drives on ``main``: ``(road store path, hellos, its segments
    as written, keyed by (from_m, to_m))``, the segments read before any test adds to the store."""
    root, on_main, _, network = sim
    url, hellos = _network_run(root, on_main, network, "net")
    with RoadStore.open(url) as s:
        segments = {(m.from_m, m.to_m): m for m in s.segments()}
    return url, hellos, segments


def test_networked_segments_and_anomalies_land_where_map_puts_them(sim, clear_run):
    root, on_main, on_side, network = sim
    url, hellos, _ = clear_run
    assert sorted(hellos) == ["v1", "v2", "v3"]
    for h in hellos.values():                              # the hello carries the placement
        assert h["road_id"] == "main" and h["road_direction"] == 1 and h["gps_fixes"] >= 50
        assert abs(h["road_offset_m"]) < 5.0 and 0.0 < h["road_offset_std_m"] < 1.0
    assert main(["map", *sum((["--drive", p] for p in on_main + on_side), []), "--network", str(network),
                 "--store", str(root / "map-roads.sqlite"), "--out", str(root / "map-out"), "--bootstrap", "0"]) == 0
    with RoadStore.open(url) as s:
        net_segs, net_an = s.segments(), s.anomalies()
    with RoadStore.open(root / "map-roads.sqlite") as s:
        map_segs = {(m.road_id, m.direction, m.from_m, m.to_m): m for m in s.segments()}
        map_an = [a for a in s.anomalies() if a.road_id == "main"]
    assert net_segs and all(s.road_id == "main" and s.direction == 1 for s in net_segs)
    common = 0
    for s in net_segs:
        assert s.lonlat.shape[0] >= 2 and s.n_vehicles == 3
        m = map_segs.get((s.road_id, s.direction, s.from_m, s.to_m))
        if m is not None:
            common += 1
            assert s.lonlat.shape == m.lonlat.shape
            assert np.abs(s.lonlat - m.lonlat).max() <= 1e-9
    assert common >= 2                                   # map has 100-200 and 200-300 (it drops 30 m at record ends)
    assert map_an and net_an
    # every anomaly map finds on main, the networked fleet finds within 2 m (great-circle) with the same kind
    for a in map_an:
        d = [float(geodesic_m(a.lon, a.lat, b.lon, b.lat)) for b in net_an if b.kind == a.kind]
        assert d and min(d) <= 2.0, (a, d)
    # and every anomaly of the networked fleet is one of map's (within 2 m, same kind)
    for b in net_an:
        d = [float(geodesic_m(a.lon, a.lat, b.lon, b.lat)) for a in map_an if a.kind == b.kind]
        assert d and min(d) <= 2.0, (b, d)
    # against the truth: IRI within 10 % of the true profile's in the band the fleet sees (0.5 Hz / 12 m/s),
    # every pothole within 2 m
    from roadcollab.experiments.drives.city import simulate_city
    from roadcollab.experiments.drives.distance_maps import band_limit_stretch
    from roadcollab.geo.network import read_network
    from roadcollab.models.iri import iri

    truth, _ = simulate_city(seed=0, network=read_network(network), vehicles=3)
    x, h = truth.road_profile("main")
    h = band_limit_stretch(h, x[1] - x[0], 0.5 / 12.0)
    for s in net_segs:
        sel = (x >= s.from_m) & (x <= s.to_m)
        true = 0.5 * (iri(h[sel, 0], x[1] - x[0]) + iri(h[sel, 1], x[1] - x[0]))
        assert abs(s.iri_m_per_km / true - 1.0) <= 0.10, (s.from_m, s.iri_m_per_km, true)
    for p in truth.potholes_lonlat():
        if p["road_id"] == "main":
            d = [float(geodesic_m(p["lon"], p["lat"], b.lon, b.lat)) for b in net_an if b.kind == "pothole"]
            assert d and min(d) <= 2.0, (p, d)
    # the anomaly's lon/lat is its measure on the road
    from roadcollab.geo.network import read_network

    road = FleetRoad(read_network(network), "main")
    for b in net_an:
        assert float(geodesic_m(*road.lonlat(b.measure_m), b.lon, b.lat)) < 1e-3
    # the live map draws every networked segment and anomaly
    live = _content(url)
    assert len(live["segments"]["features"]) == len(net_segs)
    assert len(live["anomalies"]["features"]) == len(net_an)
    # roadcollab map on the same store (the drives on side) writes the networked segments into its GeoJSON
    # and GeoPackage with their geometry
    import pyogrio

    assert main(["map", *sum((["--drive", p] for p in on_side), []), "--network", str(network), "--store", str(url),
                 "--out", str(root / "net-map"), "--bootstrap", "0"]) == 0
    fc = json.loads((root / "net-map" / "segments.geojson").read_text())
    mains = [f for f in fc["features"] if f["properties"]["road_id"] == "main"]
    assert len(mains) == len(net_segs) and len(fc["features"]) > len(net_segs)
    for f in mains:
        s = next(x for x in net_segs if x.from_m == f["properties"]["from_m"])
        assert np.abs(np.array(f["geometry"]["coordinates"]) - s.lonlat).max() <= 5e-8   # rounded to 1e-7 deg
    assert pyogrio.read_info(root / "net-map" / "roads.gpkg", layer="segments")["features"] == len(fc["features"])


def test_a_drive_on_the_parallel_road_or_without_gps_is_refused(sim):
    from roadcollab.geo.network import read_network

    root, on_main, on_side, network = sim
    road = FleetRoad(read_network(network), "main")
    d = clean_drive(load_drives(on_side[:1])[0])[0]
    with pytest.raises(ParameterError, match=r"do not follow road 'main' forward .*matched: side\+1"):
        road.place(d)
    with pytest.raises(ParameterError, match="expected lat_deg, lon_deg"):
        import dataclasses

        road.place(dataclasses.replace(d, gps=None))


def test_the_service_refuses_a_hello_off_the_fleets_road(sim):
    root, on_main, _, network = sim
    drives = [clean_drive(d)[0] for d in load_drives(on_main[:1])]
    plan = RoadPlan(fleet_id="t", min_speed=10.0, road_id="main", road_sha256=file_sha256(network))
    svc = ServiceStore(":memory:", plan)
    with pytest.raises(ParameterError, match="unacknowledged"):
        run_in_memory(drives, plan, store=svc)             # not placed: its hello has no road
    (reason,) = [e for e in svc.events("refused")]
    assert "surveys road 'main' forward" in str(reason)


def test_enroll_copies_the_network_and_every_party_checks_it(sim, tmp_path, capsys):
    _, _, _, network = sim
    assert main(["enroll", "--fleet", str(tmp_path / "f"), "--vehicles", "2", "--network", str(network),
                 "--road-id", "main"]) == 0
    assert "on road 'main'" in capsys.readouterr().out
    plan = load_plan(tmp_path / "f")
    assert plan.road_id == "main" and plan.road_sha256 == file_sha256(network)
    assert (tmp_path / "f" / ROAD_FILE).read_bytes() == network.read_bytes()
    assert FleetRoad.load(tmp_path / "f", plan).road_id == "main"
    (tmp_path / "f" / ROAD_FILE).write_text(network.read_text().replace("main", "mainx"))
    with pytest.raises(Exception, match="not the network fleet 't'|not the network fleet 'fleet'"):
        FleetRoad.load(tmp_path / "f", plan)
    assert main(["enroll", "--fleet", str(tmp_path / "g"), "--vehicles", "2", "--network", str(network),
                 "--road-id", "nope"]) == 2
    err = capsys.readouterr().err
    assert "--road-id: no road 'nope'" in err and err.count("\n") == 1
    assert main(["enroll", "--fleet", str(tmp_path / "h"), "--vehicles", "2", "--road-id", "main"]) == 2
    assert "--road-id needs --network" in capsys.readouterr().err
    assert not (tmp_path / "g").exists() and not (tmp_path / "h").exists()


def test_export_fleet_writes_the_geometry_serve_roads_writes(sim, tmp_path, capsys):
    import pyogrio

    root, on_main, _, network = sim
    assert main(["enroll", "--fleet", str(tmp_path / "f"), "--vehicles", "3", "--fleet-id", "t", "--min-speed", "12",
                 "--network", str(network), "--road-id", "main"]) == 0
    plan = load_plan(tmp_path / "f")
    road = FleetRoad.load(tmp_path / "f", plan)
    drives = [clean_drive(d)[0] for d in load_drives(on_main)]
    svc = ServiceStore(tmp_path / "s.sqlite", plan)
    with RoadStore.open(tmp_path / "roads.sqlite") as roads:
        sync = RoadSync(roads, svc, road=road)
        run_in_memory(drives, plan, store=svc, on_fused=sync, road=road)
        sync.flush()
        segs, anoms = roads.segments(), roads.anomalies()
    svc.close()
    capsys.readouterr()
    assert main(["export", "--store", str(tmp_path / "s.sqlite"), "--fleet", str(tmp_path / "f"), "--out",
                 str(tmp_path / "out")]) == 0
    assert f"road 'main': {len(segs)} segments and {len(anoms)} anomalies" in capsys.readouterr().out
    fc = json.loads((tmp_path / "out" / "segments.geojson").read_text())
    assert len(fc["features"]) == len(segs) >= 3
    for f, s in zip(sorted(fc["features"], key=lambda f: f["properties"]["from_m"]), sorted(segs, key=lambda s: s.from_m)):
        xy = np.array(f["geometry"]["coordinates"])
        assert np.abs(xy - s.lonlat).max() <= 5e-8 and 11.5 < xy[0, 0] < 11.6 and 48.1 < xy[0, 1] < 48.2
        assert np.isclose(f["properties"]["iri_m_per_km"], s.iri_m_per_km, rtol=1e-12)
    an = json.loads((tmp_path / "out" / "anomalies.geojson").read_text())
    assert len(an["features"]) == len(anoms) > 0
    assert pyogrio.read_info(tmp_path / "out" / "roads.gpkg", layer="segments")["features"] == len(segs)
    assert (tmp_path / "out" / "iri.csv").is_file()                 # and export's own files, as without --fleet
    # a fleet folder of another plan, or of a fleet without a road, is one line
    assert main(["enroll", "--fleet", str(tmp_path / "g"), "--vehicles", "1", "--fleet-id", "t"]) == 0
    assert main(["export", "--store", str(tmp_path / "s.sqlite"), "--fleet", str(tmp_path / "g"), "--out",
                 str(tmp_path / "out2")]) == 2
    err = capsys.readouterr().err
    assert "not the fleet of --store" in err and err.count("\n") == 1
    ServiceStore(tmp_path / "g.sqlite", load_plan(tmp_path / "g")).close()
    assert main(["export", "--store", str(tmp_path / "g.sqlite"), "--fleet", str(tmp_path / "g"), "--out",
                 str(tmp_path / "out2")]) == 2
    err = capsys.readouterr().err
    assert "is not enrolled on a road" in err and err.count("\n") == 1
    assert not (tmp_path / "out2").exists()


def test_a_fleet_without_a_road_keeps_its_plan_table():
    assert "road_id" not in RoadPlan().to_dict()
    assert RoadPlan.from_dict(RoadPlan().to_dict(), "x") == RoadPlan()
    p = RoadPlan(road_id="main", road_sha256="ab" * 32)
    assert RoadPlan.from_dict(p.to_dict(), "x") == p
    with pytest.raises(ParameterError, match="go together"):
        RoadPlan(road_id="main")
    with pytest.raises(ParameterError, match="road_id must be a string"):
        RoadPlan.from_dict({"road_id": 3, "road_sha256": "x"}, "x")


@pytest.mark.slow
def test_enroll_serve_fleet_over_mqtt_on_a_road(sim, tmp_path):
    """``enroll --network --road-id``, ``serve --roads --map`` with its embedded broker, ``fleet`` with three
    GPS drives on ``main``: the road store holds the in-memory run's segments (IRI and geometry), the live
    map's data has every one; a vehicle on the parallel road is refused with one line."""
    import urllib.request

    from netkit import free_port, rc, start_serve, stop

    root, on_main, on_side, network = sim
    rc("enroll", "--fleet", tmp_path / "fleet", "--vehicles", 4, "--fleet-id", "t", "--min-speed", 12,
       "--network", network, "--road-id", "main")
    port, web = free_port(), free_port()
    serve = start_serve(tmp_path / "fleet", tmp_path / "s.sqlite", tmp_path / "serve.log", listen=port,
                        extra=["--roads", tmp_path / "roads.sqlite", "--map", f"127.0.0.1:{web}"])
    try:
        rc("fleet", "--fleet", tmp_path / "fleet", *sum((["--drive", d] for d in on_main), []), "--broker",
           f"mqtt://127.0.0.1:{port}", "--timeout", 120, timeout=240)
        with urllib.request.urlopen(f"http://127.0.0.1:{web}/data.json", timeout=10) as r:
            served = json.loads(r.read())
        with RoadStore.open(tmp_path / "roads.sqlite") as s:         # the store at the same moment
            n_seg_now, n_an_now = len(s.segments()), len(s.anomalies())
        off = rc("vehicle", "--fleet", tmp_path / "fleet", "--id", "v4", "--drive", on_side[0], "--broker",
                 f"mqtt://127.0.0.1:{port}", "--timeout", 30, check=False)
    finally:
        assert stop(serve) == 0
    assert off.returncode == 2 and "matched: side+1" in off.stderr and off.stderr.count("\n") == 1
    with RoadStore.open(tmp_path / "roads.sqlite") as s:
        segs = {(x.from_m, x.to_m): x for x in s.segments()}
        n_an = len(s.anomalies())
    # what the live map served while serving: every segment and anomaly the store held then
    assert len(served["segments"]["features"]) == n_seg_now >= 3
    assert len(served["anomalies"]["features"]) == n_an_now > 0 and n_an > 0
    # the in-memory run of the same drives with the same plan: the same segments, IRI and geometry
    from roadcollab.geo.network import read_network

    road = FleetRoad(read_network(network), "main")
    drives = [clean_drive(d)[0] for d in load_drives(on_main)]
    svc = ServiceStore(":memory:", load_plan(tmp_path / "fleet"))
    with RoadStore.open(tmp_path / "mem.sqlite") as roads:
        sync = RoadSync(roads, svc, road=road)
        run_in_memory(drives, svc.plan, store=svc, on_fused=sync, road=road)
        sync.flush()
        mem = {(x.from_m, x.to_m): x for x in roads.segments()}
    assert mem.keys() == segs.keys()
    for k, x in segs.items():
        assert np.isclose(x.iri_m_per_km, mem[k].iri_m_per_km, rtol=1e-9) and x.n_vehicles == 3
        assert np.abs(x.lonlat - mem[k].lonlat).max() <= 1e-9


def test_alignment_to_the_waiting_message_undoes_a_known_shift(sim):
    """A drive moved 1.5 m along the road, aligned to its own unmoved contributions: moved back (to 0.05 m),
    contributing only on the segments it announced; with nothing waiting the engine is kept."""
    import dataclasses

    from roadcollab.geo.network import read_network
    from roadcollab.network.engine import VehicleEngine
    from roadcollab.network.fleetroad import align_to_waiting

    _, on_main, _, network = sim
    road = FleetRoad(read_network(network), "main")
    d, _ = road.place(clean_drive(load_drives(on_main[:1])[0])[0])
    plan = RoadPlan(fleet_id="t", min_speed=12.0, road_id="main", road_sha256=file_sha256(network))
    waiting = {c.segment: c for c in VehicleEngine(d, plan).contributions()}
    moved = VehicleEngine(dataclasses.replace(d, positions=d.positions + 1.5), plan)
    assert align_to_waiting(moved, {}) is moved
    again = align_to_waiting(moved, waiting)
    assert abs(again.drive.positions[0] - d.positions[0]) <= 0.05
    assert {c.segment for c in again.contributions(waiting)} <= set(moved.segments)


def test_a_secure_aggregation_fleet_on_a_road_writes_the_clear_fleets_segments(sim, clear_run):
    """The same three drives on ``main`` fused by secure aggregation (rounds of 3, k = t = 2): the road store
    holds the same segments, geometry and IRI as the clear run (the sums differ by the 2^-40 m fixed point)."""
    from roadcollab.geo.network import read_network
    from roadcollab.network.aggregation import AggregationPolicy

    root, on_main, _, network = sim
    road = FleetRoad(read_network(network), "main")
    drives = [clean_drive(d)[0] for d in load_drives(on_main)]
    vmin = min(float(road.place(d)[0].speeds().min()) for d in drives)
    plan = RoadPlan(fleet_id="t", min_speed=vmin, road_id="main", road_sha256=file_sha256(network))
    svc = ServiceStore(root / "secure-s.sqlite", plan)
    url = root / "secure-roads.sqlite"
    with RoadStore.open(url) as roads:
        sync = RoadSync(roads, svc, road=road)
        run_in_memory(drives, plan, store=svc, on_fused=sync, road=road,
                      aggregation=AggregationPolicy(mode="secure", round_size=3, min_inputs=2, threshold=2))
        sync.flush()
    assert svc.rounds() and all(r["phase"] == "finished" and len(r["used"]) == 3 for r in svc.rounds())
    svc.close()
    with RoadStore.open(url) as s:
        sec = {(m.from_m, m.to_m): m for m in s.segments()}
    ref = clear_run[2]
    assert sec.keys() == ref.keys() and sec
    for k, m in ref.items():
        assert np.array_equal(sec[k].lonlat, m.lonlat)
        assert abs(sec[k].iri_m_per_km - m.iri_m_per_km) <= 1e-9 * m.iri_m_per_km
