"""The road-condition store and the files written from it: GeoJSON (RFC 7946), GeoPackage, CSV, OpenCRG, map.html."""

import csv
import json
import re
import shutil
import subprocess

import numpy as np
import pyogrio
import pyopencrg
import pytest

from roadcollab import ParameterError
from roadcollab.geo import export
from roadcollab.geo.webmap import map_html
from roadcollab.store import RoadStore

LINE = np.array([[11.575, 48.137], [11.576, 48.137], [11.577, 48.1371]])


def _profile(n=2001, dx=0.05, seed=0):
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.normal(0, 1e-3, (n, 2)), axis=0), dx


@pytest.fixture
def store(tmp_path):
    prof, dx = _profile()
    with RoadStore.open(tmp_path / "roads.sqlite") as s:
        s.record_segment("main", 1, 0.0, 100.0, LINE, 3.0, iri_low=2.5, iri_high=3.5, n_vehicles=4, profile=prof,
                         profile_spacing_m=dx, source="t", at="2026-01-01T00:00:00+00:00")
        s.record_segment("main", 1, 0.0, 100.0, LINE, 3.2, iri_low=2.9, iri_high=3.6, n_vehicles=6, profile=prof,
                         profile_spacing_m=dx, source="t", at="2026-02-01T00:00:00+00:00")
        s.record_segment("main", -1, 0.0, 100.0, LINE, 5.0, n_vehicles=1, profile=prof, profile_spacing_m=dx,
                         at="2026-01-05T00:00:00+00:00")
        s.record_anomaly("main", 1, 50.0, 11.5757, 48.137, "pothole", "both", 0.04, 3, at="2026-01-01T00:00:00+00:00")
        s.record_anomaly("main", 1, 51.0, 11.5758, 48.137, "pothole", "both", 0.06, 1, at="2026-02-01T00:00:00+00:00")
        s.record_anomaly("main", 1, 51.0, 11.5758, 48.137, "bump", "left", 0.02, 2, at="2026-02-01T00:00:00+00:00")
        s.record_anomaly("main", 1, 80.0, 11.5762, 48.137, "pothole", "left", 0.03, 1, at="2026-02-01T00:00:00+00:00")
        yield s


def test_history_is_kept_and_latest_served(store):
    segs = store.segments()
    assert [(s.road_id, s.direction) for s in segs] == [("main", 1), ("main", -1)]
    fwd = segs[0]
    assert fwd.iri_m_per_km == 3.2 and fwd.n_vehicles == 6 and fwd.n_updates == 2
    assert fwd.iri_in_per_mi == pytest.approx(3.2 * 63.36)
    assert fwd.first_update.startswith("2026-01-01") and fwd.last_update.startswith("2026-02-01")
    assert np.array_equal(fwd.profile, _profile()[0]) and np.allclose(fwd.lonlat, LINE)
    assert segs[1].iri_low is None                          # one vehicle: no interval, stored as NULL
    hist = store.history("main", 1, 0.0)
    assert [h["iri_m_per_km"] for h in hist] == [3.0, 3.2]


def test_anomalies_merge_by_position_and_kind(store):
    an = store.anomalies()
    assert [(a.kind, a.votes) for a in an] == [("pothole", 4), ("bump", 2), ("pothole", 1)]
    merged = an[0]
    assert merged.measure_m == pytest.approx((50.0 * 3 + 51.0) / 4)            # vote-weighted mean
    assert merged.depth_m == pytest.approx((0.04 * 3 + 0.06) / 4)
    assert merged.first_seen.startswith("2026-01-01") and merged.last_seen.startswith("2026-02-01")


def test_store_refuses_foreign_files_and_urls(tmp_path):
    foreign = tmp_path / "notes.sqlite"
    foreign.write_bytes(b"my precious notes, not a database" * 10)
    before = foreign.read_bytes()
    with pytest.raises(ParameterError, match=re.escape(f"{foreign}: expected an SQLite road store")):
        RoadStore.open(foreign)
    assert foreign.read_bytes() == before
    import sqlite3
    other = tmp_path / "other.sqlite"
    with sqlite3.connect(other) as db:
        db.execute("CREATE TABLE t (x)")
    with pytest.raises(ParameterError, match="expected a roadcollab road store"):
        RoadStore.open(other)
    with pytest.raises(ParameterError, match=r"--store postgresql://user:\*\*\*@127.0.0.1:9/roads: cannot connect"):
        RoadStore.open("postgresql://user:secret@127.0.0.1:9/roads")          # port 9: nothing listens
    with pytest.raises(ParameterError, match="expected a path, sqlite:///path or postgresql"):
        RoadStore.open("mysql://x/y")
    with pytest.raises(ParameterError, match=r"direction must be \+1 or -1"):
        with RoadStore.open(tmp_path / "ok.sqlite") as s:
            s.record_segment("a", 0, 0.0, 1.0, LINE, 1.0)


# --- RFC 7946 -------------------------------------------------------------------------------------------

def _check_position(p):
    assert isinstance(p, list) and len(p) in (2, 3) and all(isinstance(v, (int, float)) for v in p)
    lon, lat = p[0], p[1]
    assert -180 <= lon <= 180 and -90 <= lat <= 90               # RFC 7946 section 3.1.1: longitude, latitude


def rfc7946_errors(doc) -> list[str]:
    """The RFC 7946 rules a FeatureCollection of Points and LineStrings must meet (sections 3.1-3.3, 4)."""
    errs = []
    if doc.get("type") != "FeatureCollection" or not isinstance(doc.get("features"), list):
        errs.append("not a FeatureCollection with a features array (3.3)")
    if "crs" in doc:
        errs.append("crs member (removed in RFC 7946, section 4)")
    for i, f in enumerate(doc.get("features", [])):
        if f.get("type") != "Feature" or "geometry" not in f or "properties" not in f:
            errs.append(f"feature {i}: type/geometry/properties (3.2)")
            continue
        if not (f["properties"] is None or isinstance(f["properties"], dict)):
            errs.append(f"feature {i}: properties must be an object or null (3.2)")
        g = f["geometry"]
        try:
            if g["type"] == "Point":
                _check_position(g["coordinates"])
            elif g["type"] == "LineString":
                assert len(g["coordinates"]) >= 2                 # 3.1.4: two or more positions
                for p in g["coordinates"]:
                    _check_position(p)
            else:
                errs.append(f"feature {i}: unexpected geometry {g['type']}")
        except AssertionError:
            errs.append(f"feature {i}: bad coordinates {g.get('coordinates')!r}")
    return errs


def test_geojson_follows_rfc7946(store, tmp_path):
    seg = export.write_geojson(tmp_path / "segments.geojson", export.segments_geojson(store.segments()))
    an = export.write_geojson(tmp_path / "anomalies.geojson", export.anomalies_geojson(store.anomalies()))
    for path, n in ((seg, 2), (an, 3)):
        doc = json.loads(path.read_text(encoding="utf-8"), parse_constant=lambda c: pytest.fail(f"{c} in JSON"))
        assert rfc7946_errors(doc) == [] and len(doc["features"]) == n
    first = json.loads(an.read_text())["features"][0]["geometry"]["coordinates"]
    assert first == pytest.approx([11.575725, 48.137], abs=1e-7)       # lon first; the vote-weighted merge
    assert rfc7946_errors({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {}, "geometry": {"type": "Point", "coordinates": [48.1, 100.0]}}]})


def test_geopackage_opens_with_the_library_and_ogrinfo(store, tmp_path):
    path = export.write_geopackage(tmp_path / "roads.gpkg", store.segments(), store.anomalies())
    layers = {name: geom for name, geom in pyogrio.list_layers(path)}
    assert layers == {"segments": "LineString", "anomalies": "Point"}
    meta, _, geom, fields = pyogrio.raw.read(path, layer="segments")
    cols = dict(zip(meta["fields"], fields))
    assert list(cols["road_id"]) == ["main", "main"] and np.allclose(cols["iri_m_per_km"], [3.2, 5.0])
    assert meta["crs"] == "EPSG:4326" and len(geom) == 2
    info = pyogrio.read_info(path, layer="anomalies")
    assert info["features"] == 3
    if shutil.which("ogrinfo") is None:
        pytest.skip("GDAL's ogrinfo is not installed (apt-get install gdal-bin)")
    out = subprocess.run(["ogrinfo", "-ro", "-so", "-al", str(path)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert re.search(r"Layer name: segments.*?Feature Count: 2", out.stdout, re.S)
    assert re.search(r"Layer name: anomalies.*?Feature Count: 3", out.stdout, re.S)


def test_linear_reference_csv(store, tmp_path):
    path = export.write_segment_csv(tmp_path / "segments.csv", store.segments())
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0])[:5] == ["road_id", "direction", "from_m", "to_m", "iri_m_per_km"]
    assert rows[0]["iri_m_per_km"] == "3.2" and rows[1]["iri_low"] == ""


def test_opencrg_round_trip(store, tmp_path):
    seg = store.segments()[0]
    path = export.write_opencrg(tmp_path / "s.crg", seg)
    road = pyopencrg.read(str(path))
    u = np.arange(seg.profile.shape[0]) * seg.profile_spacing_m
    left = road.uv_to_z(u[:-1], np.full(u.size - 1, export.TRACK_HALF_WIDTH))
    right = road.uv_to_z(u[:-1], np.full(u.size - 1, -export.TRACK_HALF_WIDTH))
    # LDFI is a text format of single precision: 1e-6 m is far below the profile's millimetres
    assert np.max(np.abs(np.asarray(left) - seg.profile[:-1, 0])) < 1e-5
    assert np.max(np.abs(np.asarray(right) - seg.profile[:-1, 1])) < 1e-5


def test_map_page_is_offline_and_escapes_names():
    seg = export.segments_geojson([])
    an = {"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": {"type": "Point",
          "coordinates": [11.5, 48.1]}, "properties": {"road_id": "</script><b>x", "kind": "pothole"}}]}
    page = map_html(seg, an)
    assert "</script><b>x" not in page                                   # cannot close the data element
    assert not re.search(r"<(script|link)[^>]+(src|href)=", page)          # nothing loaded from elsewhere
    assert "Leaflet 1.9.4" in page and "rc-segment" in page
