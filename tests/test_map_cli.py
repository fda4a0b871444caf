"""The commands of issue 21 on files: ``simulate-drives --gps [--network]`` and ``map``'s input errors."""

import json

import numpy as np

from roadcollab.cli.main import main
from roadcollab.io.drives import load_drive


def test_simulate_drives_gps_writes_the_city(tmp_path):
    out = tmp_path / "city"
    assert main(["simulate-drives", "--gps", "--out", str(out)]) == 0
    net = json.loads((out / "network.geojson").read_text())
    assert {f["properties"]["road_id"] for f in net["features"]} == {"main", "cross", "service", "side"}
    truth = json.loads((out / "truth.json").read_text())
    assert len(truth["potholes"]) == 8 and truth["gps_sigma_m"] == 3.0
    assert len(sorted(out.glob("drive*.csv"))) == 12
    assert truth["routes"][7] == [["main", 0.0, 300.0], ["side", 0.0, 400.0]]    # a turn at the T-junction
    d = load_drive(out / "drive4.csv")                      # the drive at 13-17 m/s carries a speed column
    assert d.speed_source == "speed_mps column" and d.gps.n_fixes > 100 and abs(d.gps.rate_hz - 5.0) < 0.01
    assert "roadcollab map --drive" in (out / "README.md").read_text()


def test_simulate_drives_on_a_given_network(tmp_path):
    net = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"road_id": "r1"},
         "geometry": {"type": "LineString", "coordinates": [[11.5, 48.1], [11.503, 48.1]]}}]}
    (tmp_path / "n.geojson").write_text(json.dumps(net))
    out = tmp_path / "sim"
    assert main(["simulate-drives", "--gps", "--network", str(tmp_path / "n.geojson"), "--vehicles", "2",
                 "--speeds", "14", "--out", str(out)]) == 0
    drives = sorted(out.glob("drive*.csv"))
    assert len(drives) == 2
    d = load_drive(drives[0])
    assert abs(d.speed - 14.0) < 1e-9
    # 3 m errors about a road 223 m long (0.003 degrees of longitude at 48.1 N) running east
    assert np.all(np.abs(d.gps.lat - 48.1) < 20 / 111_000) and d.gps.lon[-1] > d.gps.lon[0]


def test_map_refuses_bad_inputs_in_one_line(tmp_path, capsys):
    (tmp_path / "bad.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": []}))
    code = main(["map", "--drive", str(tmp_path / "nope.csv"), "--network", str(tmp_path / "bad.geojson"),
                 "--store", str(tmp_path / "s.sqlite"), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert "bad.geojson: expected a GeoJSON FeatureCollection of 1-10000 LineString features" in err
    assert not (tmp_path / "out").exists() and not (tmp_path / "s.sqlite").exists()
    code = main(["map", "--drive", "x.csv", "--store", "postgresql://u:pw@127.0.0.1:9/db", "--out",
                 str(tmp_path / "o2")])
    err = capsys.readouterr().err
    assert code == 2 and "--store postgresql://u:***@127.0.0.1:9/db: cannot connect" in err and "pw" not in err
    assert main(["simulate-drives", "--network", "n.geojson", "--out", str(tmp_path / "o3")]) == 2
