"""Secure aggregation between separate processes over a real broker on 127.0.0.1 (issues 19 and 20).

A fleet enrolled with ``--aggregation secure``: every vehicle process seals its relay message to the
fleet and takes part in each segment's round; the service learns only the round sums. Oracles:

- the equality of the whole issue: ``export``'s fused elevation and coverage equal ``estimate``'s
  ``final_estimate.csv`` within 1e-9 of each column's largest magnitude (the fixed point is 2^-40 m);
  the last vehicle's collaborative columns are blank (the service never sees a vehicle's estimate);
- a vehicle killed after dealing its shares: the round completes without it (Bonawitz et al.'s
  dropout recovery within k), and its fused value equals the plain mean of the other vehicles'
  inversions (the in-memory run with the same three drives, clear);
- the service's store holds no vehicle's inversion: no contribution body decodes as a clear one.
"""

import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from netkit import HAVE_MOSQUITTO, assert_same_table, free_port, rc, read_csv, start_amqtt, start_mosquitto, \
    start_serve, stop, write_drives

from roadcollab.io.drives import load_drives
from roadcollab.network.store import ServiceStore

pytestmark = pytest.mark.slow

BROKERS = ["amqtt", pytest.param("mosquitto", marks=pytest.mark.skipif(not HAVE_MOSQUITTO,
                                                                        reason="apt-get install -y mosquitto"))]
SECURE = ("--aggregation", "secure", "--min-inputs", 3, "--threshold", 3, "--round-size", 4)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("secnet")
    drives, _ = write_drives(root / "drives")
    vmin = min(float(d.speeds().min()) for d in load_drives(drives))
    rc("enroll", "--fleet", root / "fleet", "--vehicles", 4, "--fleet-id", "t", "--min-speed", repr(vmin), *SECURE)
    rc("estimate", *sum((["--drive", d] for d in drives), []), "--out", root / "estimate")
    return root, drives


def _fresh_fleet(root, tmp_path):
    """A copy of the fleet folder (each test's vehicles keep their own ledgers)."""
    import shutil

    shutil.copytree(root / "fleet", tmp_path / "fleet")
    return tmp_path / "fleet"


def _no_clear_inversion(store_path):
    st = ServiceStore(store_path)
    try:
        rows = st.contributions()
        assert rows and all(d.startswith(b"RCSEAL1\x00") for _, _, d, _ in rows)
        rounds = st.rounds()
    finally:
        st.close()
    return rounds


@pytest.mark.parametrize("kind", BROKERS)
def test_secure_fleet_equals_estimate(world, tmp_path, kind):
    root, drives = world
    fleet = _fresh_fleet(root, tmp_path)
    port = free_port()
    broker = None
    if kind == "amqtt":
        serve = start_serve(fleet, tmp_path / "s.sqlite", tmp_path / "serve.log", listen=port)
    else:
        broker = start_mosquitto(fleet, port, tmp_path / "mosq", tmp_path / "broker.log")
        serve = start_serve(fleet, tmp_path / "s.sqlite", tmp_path / "serve.log", broker=f"mqtt://127.0.0.1:{port}")
    try:
        out = rc("fleet", "--fleet", fleet, *sum((["--drive", d] for d in drives), []), "--broker",
                 f"mqtt://127.0.0.1:{port}", "--timeout", 180, timeout=300)
    finally:
        assert stop(serve) == 0
        if broker is not None:
            stop(broker)
    assert "4 of 4 vehicles done" in out.stdout, out.stdout
    assert "round 0/0: finished" in (tmp_path / "serve.log").read_text()
    rounds = _no_clear_inversion(tmp_path / "s.sqlite")
    assert rounds and all(r["phase"] == "finished" and len(r["used"]) == 4 for r in rounds)
    rc("export", "--store", tmp_path / "s.sqlite", "--out", tmp_path / "out")
    err = assert_same_table(root / "estimate" / "final_estimate.csv", tmp_path / "out" / "final_estimate.csv",
                            skip=("elevation_collaborative",))
    assert err <= 1e-9
    assert assert_same_table(root / "estimate" / "iri.csv", tmp_path / "out" / "iri.csv") <= 1e-9
    head, vals = read_csv(tmp_path / "out" / "final_estimate.csv")
    assert np.isnan(vals[:, head.index("elevation_collaborative_left")]).all()    # the service never saw it
    assert "secure aggregation" in (tmp_path / "out" / "report.md").read_text()


def _rounds_in(store_path, phase):
    st = ServiceStore(store_path)
    try:
        rs = st.rounds()
    finally:
        st.close()
    return bool(rs) and all(r["phase"] == phase for r in rs)


@pytest.mark.parametrize("kill_serve", [False, True], ids=["vehicle-killed", "vehicle-and-serve-killed"])
def test_vehicle_killed_mid_round_is_left_behind(world, tmp_path, kill_serve):
    """v4 deals its shares, then its process is killed (SIGKILL): every round finishes with v1-v3. With
    ``kill_serve``, the service is also killed (SIGKILL) while every round waits for v4's masked input, and
    restarted on its store: it replays the rounds from their journal and finishes them the same way."""
    root, drives = world
    fleet = _fresh_fleet(root, tmp_path)
    port = free_port()
    url = f"mqtt://127.0.0.1:{port}"
    broker = None
    timeout = ("--round-timeout", "8" if kill_serve else "3")
    if kill_serve:     # a broker of its own, which outlives the service and keeps its session's messages
        broker = start_amqtt(fleet, port, tmp_path / "broker.log")
        serve = start_serve(fleet, tmp_path / "s.sqlite", tmp_path / "serve.log", broker=url, extra=timeout)
    else:
        serve = start_serve(fleet, tmp_path / "s.sqlite", tmp_path / "serve.log", listen=port, extra=timeout)
    procs = []
    try:
        env_kill = {"ROADCOLLAB_TEST_DIE_AFTER": "shares"}
        import os

        for k, d in enumerate(drives):
            env = dict(os.environ, **(env_kill if k == 3 else {}))
            p = subprocess.Popen([sys.executable, "-m", "roadcollab.cli.main", "vehicle", "--fleet", fleet, "--id",
                                  f"v{k + 1}", "--drive", d, "--broker", url, "--timeout", "150"],
                                 stdout=subprocess.PIPE, text=True, env=env)
            procs.append(p)
            for line in p.stdout:
                if "contributed" in line:
                    break
        if kill_serve:
            end = time.monotonic() + 30
            while not _rounds_in(tmp_path / "s.sqlite", "masked") and time.monotonic() < end:
                time.sleep(0.05)
            assert _rounds_in(tmp_path / "s.sqlite", "masked")
            assert stop(serve, signal.SIGKILL) == -signal.SIGKILL
            serve = start_serve(fleet, tmp_path / "s.sqlite", tmp_path / "serve2.log", broker=url, extra=timeout)
        codes = [p.wait(timeout=200) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.stdout.close()
        assert stop(serve) == 0
        if broker is not None:
            stop(broker)
    assert codes[:3] == [0, 0, 0] and codes[3] == -signal.SIGKILL, codes
    rounds = _no_clear_inversion(tmp_path / "s.sqlite")
    assert rounds and all(r["phase"] == "finished" and r["roster"] == ["v1", "v2", "v3", "v4"] and
                          r["used"] == ["v1", "v2", "v3"] for r in rounds), rounds
    assert all("dropped [4]" in r["reason"] for r in rounds), [r["reason"] for r in rounds]
    # The fused value is the mean of v1-v3's inversions only: the in-memory clear run of those drives.
    from roadcollab.network.memory import run_in_memory
    from roadcollab.network.plan import RoadPlan
    from roadcollab.network.results import results_from_store

    st = ServiceStore(tmp_path / "s.sqlite")
    try:
        plan = RoadPlan.from_dict({**st.plan.to_dict(), "fleet_id": "x"}, "test")
        sec = results_from_store(st)
    finally:
        st.close()
    from roadcollab.io.drive_clean import clean_drive

    ref = results_from_store(run_in_memory([clean_drive(d)[0] for d in load_drives(drives[:3])], plan)[0])
    lo = int(round((sec.position[0] - ref.position[0]) / plan.spacing))
    assert lo >= 0
    part = ref.fused[lo:lo + len(sec.position)]
    scale = np.nanmax(np.abs(part))
    assert np.nanmax(np.abs(sec.fused - part)) / scale <= 1e-9
    assert np.array_equal(sec.coverage, ref.coverage[lo:lo + len(sec.position)])


def _open_round_owner(store_path):
    """The owner of an open round, or None."""
    st = ServiceStore(store_path)
    try:
        rows = list(st.db.execute("SELECT o.owner FROM round_owners o JOIN rounds r ON r.segment = o.segment AND "
                                  "r.epoch = o.epoch WHERE r.phase NOT IN ('finished', 'aborted')"))
    finally:
        st.close()
    return rows[0][0] if rows else None


@pytest.mark.skipif(not HAVE_MOSQUITTO, reason="apt-get install -y mosquitto")
def test_two_secure_services_share_a_store_and_one_takes_over_the_others_rounds(world, tmp_path):
    """Two ``serve --shared`` of a secure fleet against one Mosquitto and one store: each round is held by
    one of them (a claim in the store). The service holding an open round is SIGKILLed; the other takes
    its rounds over when the lease runs out (journal replay) and the equality with ``estimate`` holds."""
    root, drives = world
    fleet = _fresh_fleet(root, tmp_path)
    port = free_port()
    url = f"mqtt://127.0.0.1:{port}"
    mosq = start_mosquitto(fleet, port, tmp_path / "mosq", tmp_path / "broker.log")
    store = tmp_path / "s.sqlite"
    # A killed service takes the relay messages in flight to it along (a shared subscription does not
    # hand them to the other); the vehicle sends them again later, so rounds wait for all four vehicles.
    extra = ("--round-timeout", "8", "--round-wait", "300")
    serves = [start_serve(fleet, store, tmp_path / f"{k}.log", broker=url, shared=True, extra=extra) for k in "ab"]
    fleet_run = subprocess.Popen([sys.executable, "-m", "roadcollab.cli.main", "fleet", "--fleet", fleet,
                                  *sum((["--drive", str(d)] for d in drives), []), "--broker", url, "--timeout",
                                  "180"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    killed = None
    try:
        end = time.monotonic() + 120
        while killed is None and time.monotonic() < end and fleet_run.poll() is None:
            owner = _open_round_owner(store) if store.exists() else None
            if owner is not None:
                killed = next(p for p in serves if owner.endswith(f"-{p.pid}"))
                assert stop(killed, signal.SIGKILL) == -signal.SIGKILL
            time.sleep(0.05)
        out, _ = fleet_run.communicate(timeout=240)
    finally:
        if fleet_run.poll() is None:
            fleet_run.kill()
            fleet_run.communicate()
        codes = [stop(p) for p in serves if p is not killed]
        stop(mosq)
    assert killed is not None, "no round was seen open"
    assert codes == [0] and "4 of 4 vehicles done" in out, out
    survivor = tmp_path / ("b.log" if killed is serves[0] else "a.log")
    assert "taken over in phase" in survivor.read_text()
    rounds = _no_clear_inversion(store)
    assert rounds and all(r["phase"] == "finished" and len(r["used"]) == 4 for r in rounds), rounds
    rc("export", "--store", store, "--out", tmp_path / "out")
    err = assert_same_table(root / "estimate" / "final_estimate.csv", tmp_path / "out" / "final_estimate.csv",
                            skip=("elevation_collaborative",))
    assert err <= 1e-9
