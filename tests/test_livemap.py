"""The live map of ``serve --map`` (network/livemap.py): the page and its JSON over HTTP on 127.0.0.1, and
(slow) in headless Chromium: the drawn segments equal the store's and grow while more drives are added."""

import importlib.util
import json
import os
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from roadcollab.network.livemap import LiveMap
from roadcollab.store import RoadStore

ROOT = Path(__file__).resolve().parents[1]
LINE = np.array([[11.575, 48.137], [11.576, 48.137], [11.577, 48.1371]])


def _get(url):
    with urllib.request.urlopen(url, timeout=10) as r:
        return r.status, r.headers["Content-Type"], r.read()


def test_page_and_data_follow_the_store(tmp_path):
    url = tmp_path / "roads.sqlite"
    with RoadStore.open(url) as s:
        s.record_segment("main", 1, 0.0, 100.0, LINE, 3.0, n_vehicles=2)
        s.record_segment("t", 1, 0.0, 100.0, np.zeros((0, 2)), 2.0, n_vehicles=2)   # no geometry: not drawn
    live = LiveMap(url).start()
    try:
        assert live.host == "127.0.0.1" and live.port > 0
        code, kind, body = _get(live.url)
        assert code == 200 and kind.startswith("text/html")
        page = body.decode()
        assert "rcPoll" in page and "L.geoJSON" in page and "https://" not in page.split("rc-data")[0][-200:]
        d1 = json.loads(_get(live.url + "data.json")[2])
        assert len(d1["segments"]["features"]) == 1 and d1["anomalies"]["features"] == []
        with RoadStore.open(url) as s:
            s.record_segment("main", 1, 100.0, 200.0, LINE + [0.001, 0.0], 5.0, n_vehicles=1)
            s.record_anomaly("main", 1, 50.0, 11.5757, 48.137, "pothole", "both", 0.04, 3)
        d2 = json.loads(_get(live.url + "data.json")[2])
        assert len(d2["segments"]["features"]) == 2 and len(d2["anomalies"]["features"]) == 1
        assert d2["version"] != d1["version"]
        with pytest.raises(urllib.error.HTTPError):
            _get(live.url + "etc/passwd")
    finally:
        live.stop()


def test_serve_map_option_is_checked(tmp_path, capsys):
    from roadcollab.cli.main import main

    assert main(["serve", "--fleet", str(tmp_path), "--store", str(tmp_path / "s.sqlite"), "--map"]) == 2
    assert "--map: needs --roads" in capsys.readouterr().err
    assert main(["serve", "--fleet", str(tmp_path), "--store", str(tmp_path / "s.sqlite"), "--roads",
                 str(tmp_path / "r.sqlite"), "--map", "127.0.0.1:99999"]) == 2
    assert "--map 127.0.0.1:99999: expected HOST:PORT" in capsys.readouterr().err
    assert not (tmp_path / "s.sqlite").exists()


@pytest.mark.slow
def test_live_map_in_headless_chromium_grows(tmp_path):
    spec = importlib.util.spec_from_file_location("map_screenshot", ROOT / "tools" / "map_screenshot.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    if not Path(mod.CHROMIUM).exists() or importlib.util.find_spec("playwright") is None:
        if os.environ.get("CI"):
            pytest.fail("CI needs chromium (apt-get install -y chromium) and playwright (pip)")
        pytest.skip("needs /usr/bin/chromium and playwright")
    from playwright.sync_api import sync_playwright

    from roadcollab.cli.map import map_command
    from roadcollab.experiments.drives.city import write_city

    (tmp_path / "city").mkdir()
    files = write_city(tmp_path / "city", seed=0)
    drives = [str(p) for p in files["drives"]]
    store = tmp_path / "roads.sqlite"
    map_command(drives[:2], tmp_path / "out1", store_url=store, command="test", network_path=files["network"],
                bootstrap=0, seed=0)
    live = LiveMap(store, poll_s=0.5).start()
    foreign, errors = [], []
    count = "() => document.querySelectorAll('path.rc-segment').length"
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=mod.CHROMIUM, args=mod.ARGS, timeout=60_000)
            try:
                page = browser.new_context(viewport={"width": 1200, "height": 800}).new_page()
                page.route("**/*", lambda route: route.continue_() if route.request.url.startswith(live.url)
                           else (foreign.append(route.request.url), route.abort()))
                page.on("pageerror", lambda e: errors.append(str(e)))
                page.goto(live.url, timeout=60_000)
                page.wait_for_function("window.roadcollab !== undefined && window.roadcollab.polls > 0",
                                       timeout=60_000)
                with RoadStore.open(store) as s:
                    n1 = len(s.segments())
                assert page.evaluate(count) == n1 > 0
                map_command(drives, tmp_path / "out2", store_url=store, command="test",
                            network_path=files["network"], bootstrap=0, seed=0)
                with RoadStore.open(store) as s:
                    n2, n_an = len(s.segments()), len(s.anomalies())
                assert n2 > n1
                page.wait_for_function(f"({count})() === {n2}", timeout=60_000)
                assert page.evaluate("() => document.querySelectorAll('path.rc-anomaly').length") == n_an
                page.wait_for_timeout(500)
                page.screenshot(path=str(tmp_path / "map-live.png"))
            finally:
                browser.close()
    finally:
        live.stop()
    assert foreign == [] and errors == []
    assert (tmp_path / "map-live.png").stat().st_size > 10_000
    if os.environ.get("ROADCOLLAB_DOCS_SCREENSHOT"):
        (ROOT / "docs" / "map-live.png").write_bytes((tmp_path / "map-live.png").read_bytes())


@pytest.mark.slow
def test_live_map_draws_the_networked_fleet_in_headless_chromium(tmp_path):
    """The networked fleet on a road (GPS drives of ``simulate-drives --gps``, in-memory transport, RoadSync
    writing the store while the page is open): the page draws the store's segments and anomaly markers."""
    spec = importlib.util.spec_from_file_location("map_screenshot", ROOT / "tools" / "map_screenshot.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    if not Path(mod.CHROMIUM).exists() or importlib.util.find_spec("playwright") is None:
        if os.environ.get("CI"):
            pytest.fail("CI needs chromium (apt-get install -y chromium) and playwright (pip)")
        pytest.skip("needs /usr/bin/chromium and playwright")
    from playwright.sync_api import sync_playwright

    from roadcollab.experiments.drives.city import write_city
    from roadcollab.geo.network import read_network
    from roadcollab.io.drive_clean import clean_drive
    from roadcollab.io.drives import load_drives
    from roadcollab.network.fleetroad import FleetRoad, file_sha256
    from roadcollab.network.memory import run_in_memory
    from roadcollab.network.plan import RoadPlan
    from roadcollab.network.roadsync import RoadSync
    from roadcollab.network.store import ServiceStore

    (tmp_path / "city").mkdir()
    files = write_city(tmp_path / "city", seed=0)
    road = FleetRoad(read_network(files["network"]), "main")
    drives = [clean_drive(d)[0] for d in load_drives([str(p) for p in files["drives"][:3]])]   # main + cross
    plan = RoadPlan(fleet_id="city", min_speed=12.0, road_id="main", road_sha256=file_sha256(files["network"]))
    svc = ServiceStore(tmp_path / "s.sqlite", plan)
    store = tmp_path / "roads.sqlite"
    RoadStore.open(store).close()
    live = LiveMap(store, poll_s=0.5).start()
    foreign, errors = [], []
    count = "() => document.querySelectorAll('path.rc-segment').length"
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=mod.CHROMIUM, args=mod.ARGS, timeout=60_000)
            try:
                page = browser.new_context(viewport={"width": 1200, "height": 800}).new_page()
                page.route("**/*", lambda route: route.continue_() if route.request.url.startswith(live.url)
                           else (foreign.append(route.request.url), route.abort()))
                page.on("pageerror", lambda e: errors.append(str(e)))
                page.goto(live.url, timeout=60_000)
                page.wait_for_function("window.roadcollab !== undefined && window.roadcollab.polls > 0",
                                       timeout=60_000)
                assert page.evaluate(count) == 0                  # nothing in the store yet
                with RoadStore.open(store) as roads:
                    sync = RoadSync(roads, svc, road=road)
                    run_in_memory(drives, plan, store=svc, on_fused=sync, road=road)
                    sync.flush()
                with RoadStore.open(store) as s:
                    n_seg, n_an = len(s.segments()), len(s.anomalies())
                    assert all(x.lonlat.shape[0] >= 2 for x in s.segments())
                assert n_seg >= 4 and n_an > 0
                page.wait_for_function(f"({count})() === {n_seg}", timeout=60_000)
                assert page.evaluate("() => document.querySelectorAll('path.rc-anomaly').length") == n_an
                page.wait_for_timeout(500)
                page.screenshot(path=str(tmp_path / "map-network.png"))
            finally:
                browser.close()
    finally:
        live.stop()
        svc.close()
    assert foreign == [] and errors == []
    assert (tmp_path / "map-network.png").stat().st_size > 10_000
