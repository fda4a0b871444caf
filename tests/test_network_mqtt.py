"""The networked run against real brokers on 127.0.0.1: the main equality and the transport's defences.

THE test of issue 19: the same 4 drives at different speeds (12, 15, 18 and 13-17 m/s) through
``roadcollab estimate`` and through ``serve`` + ``fleet`` (one ``vehicle`` process per drive) + ``export``
give the same ``final_estimate.csv`` (every number within 1e-9 of its column's largest magnitude), against
the embedded broker (amqtt) and against Mosquitto. Each test starts its own broker and service on free
loopback ports and stops them by pid.
"""

import time

import numpy as np
import pytest

from netkit import HAVE_MOSQUITTO, assert_same_table, free_port, rc, start_amqtt, start_mosquitto, start_serve, \
    stop, write_drives
from roadcollab import ParameterError
from roadcollab.io.drives import load_drives
from roadcollab.network.fleetdir import Login, load_login
from roadcollab.network.mqtt_client import MqttClient
from roadcollab.network.store import ServiceStore

pytestmark = pytest.mark.slow
BROKERS = ["amqtt", pytest.param("mosquitto", marks=pytest.mark.skipif(not HAVE_MOSQUITTO,
                                                                        reason="apt-get install -y mosquitto"))]


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """Drive files, a fleet enrolled for them, and what ``roadcollab estimate`` makes of them."""
    root = tmp_path_factory.mktemp("net")
    drives, _ = write_drives(root / "drives")
    vmin = min(float(d.speeds().min()) for d in load_drives(drives))
    rc("enroll", "--fleet", root / "fleet", "--vehicles", 6, "--fleet-id", "t", "--min-speed", repr(vmin))
    rc("estimate", *sum((["--drive", d] for d in drives), []), "--out", root / "estimate")
    return root, drives


@pytest.fixture
def broker(world, request, tmp_path):
    """A broker of the requested kind on a free port: ``(url, process)``."""
    root, _ = world
    port = free_port()
    if request.param == "amqtt":
        p = start_amqtt(root / "fleet", port, tmp_path / "broker.log")
    else:
        p = start_mosquitto(root / "fleet", port, tmp_path / "mosq", tmp_path / "broker.log")
    yield f"mqtt://127.0.0.1:{port}", p, request.param
    stop(p)


def _fleet(root, drives, url, *extra, timeout=240):
    return rc("fleet", "--fleet", root / "fleet", *sum((["--drive", d] for d in drives), []), "--broker", url,
              "--timeout", 120, *extra, timeout=timeout)


def _export_equal(root, store, out, skip=()):
    rc("export", "--store", store, "--out", out)
    return assert_same_table(root / "estimate" / "final_estimate.csv", out / "final_estimate.csv", skip=skip)


def test_estimate_equals_serve_with_its_embedded_broker(world, tmp_path):
    root, drives = world
    port = free_port()
    serve = start_serve(root / "fleet", tmp_path / "s.sqlite", tmp_path / "serve.log", listen=port)
    try:
        _fleet(root, drives, f"mqtt://127.0.0.1:{port}")
    finally:
        assert stop(serve) == 0
    assert "stopped:" in (tmp_path / "serve.log").read_text().splitlines()[-1]
    assert _export_equal(root, tmp_path / "s.sqlite", tmp_path / "out") <= 1e-9
    for f in ("road_estimates.csv", "iri.csv"):
        assert_same_table(root / "estimate" / f, tmp_path / "out" / f)


@pytest.mark.parametrize("broker", BROKERS, indirect=True)
def test_estimate_equals_serve_and_concurrent_vehicles(world, broker, tmp_path):
    """All four vehicles at once through an external broker: the fused estimate (an average) is the same. The
    last vehicle's collaborative column depends on which message was waiting when it passed (the relay's
    order), so it is not compared here; the sequential test above compares it."""
    root, drives = world
    url, _, _ = broker
    serve = start_serve(root / "fleet", tmp_path / "s.sqlite", tmp_path / "serve.log", broker=url)
    try:
        _fleet(root, drives, url, "--concurrent")
    finally:
        assert stop(serve) == 0
    assert _export_equal(root, tmp_path / "s.sqlite", tmp_path / "out", skip=("elevation_collaborative",)) <= 1e-9
    st = ServiceStore(tmp_path / "s.sqlite").status()
    assert st["contributions"] == 24 and st["refused"] == {}


@pytest.mark.parametrize("broker", BROKERS, indirect=True)
def test_credentials_and_acl(world, broker, tmp_path):
    """No login, a wrong password: refused. v1 cannot publish on v2's topics or read v2's acks."""
    root, _ = world
    url, _, _ = broker
    with pytest.raises(ParameterError, match="refused user 'v1'"):
        MqttClient(url, Login("v1", "not-the-password"), "rc-test-bad").connect(timeout=10)
    with pytest.raises(ParameterError, match="refused user 'nobody'"):
        MqttClient(url, Login("nobody", ""), "rc-test-anon").connect(timeout=10)
    watcher = MqttClient(url, load_login(root / "fleet" / "service" / "broker.toml"), "rc-test-watch").connect()
    v1 = MqttClient(url, load_login(root / "fleet" / "vehicles" / "v1" / "broker.toml"), "rc-test-v1").connect()
    try:
        watcher.subscribe("rc/t/v/#")
        v1.subscribe("rc/t/ack/v2")
        time.sleep(1.0)
        v1.publish("rc/t/v/v2/hello", b"forged")           # another vehicle's topic: the ACL drops it
        watcher.publish("rc/t/ack/v2", b"for v2 only")
        v1.publish("rc/t/v/v1/hello", b"own topic")        # its own topic: delivered
        got = []
        end = time.monotonic() + 10
        while time.monotonic() < end and not any(t == "rc/t/v/v1/hello" for t, _ in got):
            m = watcher.receive(0.2)
            if m:
                got.append(m)
        time.sleep(1.0)
        while (m := watcher.receive(0.1)) is not None:
            got.append(m)
        assert ("rc/t/v/v1/hello", b"own topic") in got
        assert not any(t.startswith("rc/t/v/v2") for t, _ in got)
        assert v1.receive(0.5) is None                     # v2's ack never reached v1
    finally:
        v1.close()
        watcher.close()


@pytest.mark.parametrize("broker", BROKERS, indirect=True)
def test_hostile_messages_change_nothing(world, broker, tmp_path):
    """With v1's valid login: random bytes on every topic it may publish on, and replayed copies of the
    other vehicles' messages, change no result and crash nothing; copies of its own are applied once."""
    root, drives = world
    url, _, _ = broker
    store = tmp_path / "s.sqlite"
    serve = start_serve(root / "fleet", store, tmp_path / "serve.log", broker=url)
    try:
        _fleet(root, drives[:2], url)
        before = ServiceStore(store).status()
        rows = ServiceStore(store).db.execute("SELECT vid, segment, envelope FROM contributions").fetchall()
        v1 = MqttClient(url, load_login(root / "fleet" / "vehicles" / "v1" / "broker.toml"), "rc-test-v1b").connect()
        rng = np.random.default_rng(5)
        try:
            for s in range(8):
                for t in (f"rc/t/v/v1/seg/{s}", "rc/t/v/v1/hello", f"rc/t/v/v1/seg/{s}/x", "rc/t/v/v1"):
                    v1.publish(t, rng.bytes(int(rng.integers(0, 4000))))
            for _vid, s, env in rows:
                v1.publish(f"rc/t/v/v1/seg/{s}", bytes(env))     # every stored message replayed as v1's
            time.sleep(5.0)
        finally:
            v1.close()
        after = ServiceStore(store).status()
        assert serve.poll() is None
    finally:
        assert stop(serve) == 0
    assert after["contributions"] == before["contributions"] == 12
    assert after["duplicates"] >= 6                        # v1's own copies, applied once
    # 24 random payloads on seg/s, hello and seg/s/x, and v2's 6 envelopes replayed as v1's (the 8 on
    # "rc/t/v/v1" itself are refused by the service or dropped by the broker's ACL, depending on the broker).
    assert sum(after["refused"].values()) >= 24 + 6


def test_missing_store_and_bad_broker_url_are_one_line(tmp_path):
    p = rc("status", "--store", tmp_path / "none.sqlite", check=False)
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and "not found" in p.stderr
    p = rc("vehicle", "--fleet", tmp_path, "--id", "v1", "--drive", "x.csv", "--broker", "http://x", check=False)
    assert p.returncode == 2 and "expected mqtt://HOST:PORT" in p.stderr and "Traceback" not in p.stderr


@pytest.mark.skipif(not HAVE_MOSQUITTO, reason="apt-get install -y mosquitto")
def test_two_services_share_the_segments_through_a_shared_subscription(world, tmp_path):
    """Two ``serve --shared`` instances against one Mosquitto split the messages ($share/t/...) and
    write one store (SQLite, each message one BEGIN IMMEDIATE transaction): the equality holds."""
    root, drives = world
    port = free_port()
    url = f"mqtt://127.0.0.1:{port}"
    mosq = start_mosquitto(root / "fleet", port, tmp_path / "mosq", tmp_path / "broker.log")
    store = tmp_path / "s.sqlite"
    a = start_serve(root / "fleet", store, tmp_path / "a.log", broker=url, shared=True)
    b = start_serve(root / "fleet", store, tmp_path / "b.log", broker=url, shared=True)
    try:
        _fleet(root, drives, url, "--concurrent")
    finally:
        codes = [stop(a), stop(b)]
        stop(mosq)
    assert codes == [0, 0]
    assert _export_equal(root, store, tmp_path / "out", skip=("elevation_collaborative",)) <= 1e-9
    logs = [(tmp_path / f).read_text() for f in ("a.log", "b.log")]
    assert all("accepted" in t for t in logs), "both services applied contributions"
