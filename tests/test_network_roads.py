"""The service's results in the road-condition store while it serves (serve --roads; network/roadsync.py)."""

import csv
import json
import urllib.request

import numpy as np
import pytest

from netkit import write_drives
from roadcollab.cli.main import main
from roadcollab.io.drive_clean import clean_drive
from roadcollab.io.drives import load_drives
from roadcollab.network.memory import run_in_memory
from roadcollab.network.plan import RoadPlan
from roadcollab.network.roadsync import RoadSync
from roadcollab.network.store import ServiceStore
from roadcollab.store import RoadStore


class _Late:
    """Opens the RoadSync on the service's store at the first call (run_in_memory creates the store)."""

    def __init__(self, roads):
        self.roads, self.sync, self.calls = roads, None, 0

    def __call__(self, segment, store):
        self.calls += 1
        if self.sync is None:
            self.sync = RoadSync(self.roads, store)
        self.sync(segment, store)


def _drives(tmp_path, speeds):
    paths, _ = write_drives(tmp_path / "drives", speeds=speeds)
    drives = [clean_drive(d)[0] for d in load_drives(paths)]
    return paths, drives, RoadPlan(fleet_id="t", min_speed=min(float(d.speeds().min()) for d in drives))


@pytest.mark.slow  # 7 s: a served fleet end to end
def test_road_store_follows_the_service_and_equals_export(tmp_path, capsys):
    paths, drives, plan = _drives(tmp_path, (12.0, 15.0, 18.0))
    svc = ServiceStore(tmp_path / "s.sqlite", plan)
    roads = RoadStore.open(tmp_path / "roads.sqlite")
    hook = _Late(roads)
    run_in_memory(drives[:2], plan, store=svc, on_fused=hook)
    assert hook.calls == 12                         # one per accepted contribution (6 segments, 2 vehicles)
    first = {s.from_m: s for s in roads.segments()}
    assert first and all(s.road_id == "t" and s.n_vehicles == 2 for s in first.values())
    # the road store's IRI is export's iri.csv, segment by segment
    assert main(["export", "--store", str(tmp_path / "s.sqlite"), "--out", str(tmp_path / "net")]) == 0
    with open(tmp_path / "net" / "iri.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(first)
    for row in rows:
        s = first[float(row["start_m"])]
        assert np.isclose(s.iri_m_per_km, 0.5 * (float(row["iri_left_m_per_km"]) + float(row["iri_right_m_per_km"])),
                          rtol=1e-12)
        assert np.isclose(s.iri_in_per_mi, s.iri_m_per_km * 63.36)
        if s.from_m >= 7.0:                         # both drives cover it whole (the second starts at 7 m)
            assert s.iri_low is not None and s.iri_low <= s.iri_m_per_km <= s.iri_high
        else:
            assert s.iri_low is None
        assert s.profile.shape[1] == 2 and np.isfinite(s.profile).all()
    with open(tmp_path / "net" / "anomalies.csv") as f:
        exported = list(csv.DictReader(f))
    stored = roads.anomalies()
    assert len(stored) == len(exported)
    for a, r in zip(stored, sorted(exported, key=lambda r: float(r["position_m"]))):
        assert abs(a.measure_m - float(r["position_m"])) <= 2.0 and a.kind == r["kind"] and a.votes == 2
    # a restarted service on the same stores adds no copy; a third vehicle adds history, not overwrites
    again = RoadSync(roads, svc)
    again._dirty = True
    assert again.flush() == (0, 0)
    run_in_memory(drives, plan, store=svc, on_fused=RoadSync(roads, svc))   # v1, v2 again (applied once), v3
    later = {s.from_m: s for s in roads.segments()}
    assert later.keys() == first.keys()
    assert all(s.n_vehicles == 3 and s.n_updates >= 2 for s in later.values())
    assert all(later[k].first_update == first[k].first_update for k in later)
    assert all(a.votes == 3 for a in roads.anomalies())
    roads.close()
    capsys.readouterr()
    assert main(["status", "--store", str(tmp_path / "s.sqlite"), "--roads", str(tmp_path / "roads.sqlite")]) == 0
    out = capsys.readouterr().out
    assert f"road store {tmp_path / 'roads.sqlite'}: {len(first)} segments on 1 road(s)" in out


def test_status_of_a_missing_road_store_is_one_line(tmp_path, capsys):
    _, drives, plan = _drives(tmp_path, (12.0,))
    run_in_memory(drives, plan, store=ServiceStore(tmp_path / "s.sqlite", plan))
    assert main(["status", "--store", str(tmp_path / "s.sqlite"), "--roads", str(tmp_path / "none.sqlite")]) == 2
    err = capsys.readouterr().err
    assert "--roads" in err and err.count("\n") == 1
    assert not (tmp_path / "none.sqlite").exists()


@pytest.mark.slow
def test_serve_roads_and_map_over_mqtt(tmp_path):
    """``serve --roads --map`` with its embedded broker and 4 vehicle processes: the road store holds
    ``estimate``'s iri.csv, the terminal shows the counts, the live map answers (nothing to draw: no GPS)."""
    from netkit import free_port, rc, start_serve, stop

    drives, _ = write_drives(tmp_path / "drives")
    vmin = min(float(d.speeds().min()) for d in load_drives(drives))
    rc("enroll", "--fleet", tmp_path / "fleet", "--vehicles", 4, "--fleet-id", "t", "--min-speed", repr(vmin))
    rc("estimate", *sum((["--drive", d] for d in drives), []), "--out", tmp_path / "estimate")
    port, web = free_port(), free_port()
    serve = start_serve(tmp_path / "fleet", tmp_path / "s.sqlite", tmp_path / "serve.log", listen=port,
                        extra=["--roads", tmp_path / "roads.sqlite", "--map", f"127.0.0.1:{web}"])
    try:
        rc("fleet", "--fleet", tmp_path / "fleet", *sum((["--drive", d] for d in drives), []), "--broker",
           f"mqtt://127.0.0.1:{port}", "--timeout", 120, timeout=240)
        with urllib.request.urlopen(f"http://127.0.0.1:{web}/data.json", timeout=10) as r:
            live = json.loads(r.read())
    finally:
        assert stop(serve) == 0
    log = (tmp_path / "serve.log").read_text()
    assert f"live map of {tmp_path / 'roads.sqlite'} on http://127.0.0.1:{web}/" in log
    assert "4 vehicles, " in log and "road store" in log and "segment estimates" in log
    assert live["segments"]["features"] == []                     # the network's drives carry no GPS
    with open(tmp_path / "estimate" / "iri.csv") as f:
        rows = list(csv.DictReader(f))
    with RoadStore.open(tmp_path / "roads.sqlite") as roads:
        segs = {s.from_m: s for s in roads.segments()}
    assert len(segs) == len(rows)
    for row in rows:
        assert np.isclose(segs[float(row["start_m"])].iri_m_per_km, float(row["iri_m_per_km"]), rtol=1e-9)
        assert segs[float(row["start_m"])].n_vehicles >= 1
