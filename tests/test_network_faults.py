"""Faults the networked run survives, each against a real broker on 127.0.0.1 (issue 19, "Faults").

Every test ends with the main equality: the exported ``final_estimate.csv`` equals ``roadcollab estimate``'s
on the same drives (within 1e-9 of each column's largest magnitude), i.e. nothing was lost and nothing
counted twice (the ``coverage`` column counts the inversions applied at every point).
"""

import signal
import sqlite3
import time

import pytest

from netkit import HAVE_MOSQUITTO, PY, assert_same_table, free_port, rc, start, start_amqtt, start_mosquitto, \
    start_serve, stop, write_drives
from roadcollab.io.drives import load_drives

pytestmark = pytest.mark.slow
BROKERS = ["amqtt", pytest.param("mosquitto", marks=pytest.mark.skipif(not HAVE_MOSQUITTO,
                                                                        reason="apt-get install -y mosquitto"))]


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("faults")
    drives, _ = write_drives(root / "drives")
    vmin = min(float(d.speeds().min()) for d in load_drives(drives))
    rc("enroll", "--fleet", root / "fleet", "--vehicles", 4, "--fleet-id", "t", "--min-speed", repr(vmin))
    rc("estimate", *sum((["--drive", d] for d in drives), []), "--out", root / "estimate")
    return root, drives


def _start_broker(kind, root, port, tmp_path):
    if kind == "amqtt":
        return start_amqtt(root / "fleet", port, tmp_path / "broker.log")
    return start_mosquitto(root / "fleet", port, tmp_path / "mosq", tmp_path / "broker.log")


def _count(store, timeout_s: float = 0.0) -> int:
    try:
        with sqlite3.connect(store, timeout=5) as db:
            return db.execute("SELECT COUNT(*) FROM contributions").fetchone()[0]
    except sqlite3.OperationalError:                   # not created yet
        return 0


def _wait_count(store, n: int, timeout: float = 180.0, procs=()) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if _count(store) >= n:
            return
        time.sleep(0.2)
    raise TimeoutError(f"{store}: fewer than {n} contributions after {timeout} s")


def _fleet_proc(root, drives, url, log, *extra):
    return start(PY, "-m", "roadcollab.cli.main", "fleet", "--fleet", root / "fleet",
                 *sum((["--drive", d] for d in drives), []), "--broker", url, "--timeout", 200, *extra, log=log)


def _equal(root, store, out, skip=("elevation_collaborative",)):
    """The fused estimate equals estimate's; the collaborative column depends on the relay's order (vehicles
    run concurrently or restart), so it is left out."""
    rc("export", "--store", store, "--out", out)
    assert_same_table(root / "estimate" / "final_estimate.csv", out / "final_estimate.csv", skip=skip)
    with sqlite3.connect(store) as db:
        assert db.execute("SELECT COUNT(*) FROM contributions").fetchone()[0] == 24


@pytest.mark.parametrize("kind", BROKERS)
def test_broker_killed_and_restarted_mid_run(world, kind, tmp_path):
    root, drives = world
    port = free_port()
    url = f"mqtt://127.0.0.1:{port}"
    broker = _start_broker(kind, root, port, tmp_path)
    serve = start_serve(root / "fleet", tmp_path / "s.sqlite", tmp_path / "serve.log", broker=url)
    fleet = _fleet_proc(root, drives, url, tmp_path / "fleet.log")
    try:
        _wait_count(tmp_path / "s.sqlite", 8)
        stop(broker, signal.SIGKILL)
        time.sleep(2.0)
        broker = _start_broker(kind, root, port, tmp_path)
        assert fleet.wait(300) == 0, (tmp_path / "fleet.log").read_text()
    finally:
        stop(fleet)
        code = stop(serve)
        stop(broker)                                    # stopped even when serve's exit code is wrong
    assert code == 0
    _equal(root, tmp_path / "s.sqlite", tmp_path / "out")


@pytest.mark.parametrize("kind", BROKERS)
def test_serve_sigkilled_and_restarted_on_its_store(world, kind, tmp_path):
    root, drives = world
    port = free_port()
    url = f"mqtt://127.0.0.1:{port}"
    broker = _start_broker(kind, root, port, tmp_path)
    store = tmp_path / "s.sqlite"
    serve = start_serve(root / "fleet", store, tmp_path / "serve.log", broker=url)
    fleet = _fleet_proc(root, drives, url, tmp_path / "fleet.log", "--concurrent")
    try:
        _wait_count(store, 6)
        stop(serve, signal.SIGKILL)
        time.sleep(1.0)
        serve = start_serve(root / "fleet", store, tmp_path / "serve2.log", broker=url)
        assert "holds" in (tmp_path / "serve2.log").read_text()
        assert fleet.wait(300) == 0, (tmp_path / "fleet.log").read_text()
    finally:
        stop(fleet)
        code = stop(serve)
        stop(broker)                                    # stopped even when serve's exit code is wrong
    assert code == 0
    _equal(root, store, tmp_path / "out")


def test_a_vehicle_dies_mid_run(world, tmp_path):
    """v2 is SIGKILLed: v1, v3 and v4 finish without it; restarted, v2 sends only what is missing."""
    root, drives = world
    port = free_port()
    url = f"mqtt://127.0.0.1:{port}"
    store = tmp_path / "s.sqlite"
    serve = start_serve(root / "fleet", store, tmp_path / "serve.log", listen=port)

    def vehicle(k, log):
        return start(PY, "-m", "roadcollab.cli.main", "vehicle", "--fleet", root / "fleet", "--id", f"v{k}",
                     "--drive", drives[k - 1], "--broker", url, "--timeout", 200, log=log)

    try:
        v2 = vehicle(2, tmp_path / "v2.log")
        end = time.monotonic() + 120
        while time.monotonic() < end and "v2" not in (tmp_path / "serve.log").read_text():
            time.sleep(0.05)
        stop(v2, signal.SIGKILL)
        others = [vehicle(k, tmp_path / f"v{k}.log") for k in (1, 3, 4)]
        assert [p.wait(300) for p in others] == [0, 0, 0]
        assert _count(store) >= 18
        again = vehicle(2, tmp_path / "v2b.log")
        assert again.wait(300) == 0, (tmp_path / "v2b.log").read_text()
    finally:
        assert stop(serve) == 0
    rc("export", "--store", store, "--out", tmp_path / "out")
    with sqlite3.connect(store) as db:
        assert db.execute("SELECT vid FROM vehicles ORDER BY order_no").fetchall()[0] == ("v2",)
    _equal(root, store, tmp_path / "out")
