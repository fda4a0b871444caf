"""TLS between the fleet and its broker (``enroll --tls``, ``mqtts://``), against both brokers on 127.0.0.1.

Oracles: a vehicle login with the fleet CA connects and a message goes round; the same port without TLS,
a client trusting another fleet's CA, and a host name the certificate does not carry are refused; and a
whole run (``serve`` with its embedded broker over TLS, ``fleet``, ``export``) gives ``estimate``'s
``final_estimate.csv`` (1e-9 of each column's largest magnitude), as without TLS.
"""

import time
from dataclasses import replace

import pytest
from netkit import HAVE_MOSQUITTO, assert_same_table, free_port, rc, start_amqtt, start_mosquitto, start_serve, \
    stop, write_drives

from roadcollab import ParameterError
from roadcollab.io.drives import load_drives
from roadcollab.network.fleetdir import load_login
from roadcollab.network.mqtt_client import MqttClient

# paho leaves the socket of a refused TLS handshake to the garbage collector (its reconnect loop): the refusals
# below are the point of the test, so their ResourceWarnings are not ours to fix here.
pytestmark = [pytest.mark.slow, pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")]

BROKERS = ["amqtt", pytest.param("mosquitto", marks=pytest.mark.skipif(not HAVE_MOSQUITTO,
                                                                        reason="apt-get install -y mosquitto"))]


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("tls")
    drives, _ = write_drives(root / "drives")
    vmin = min(float(d.speeds().min()) for d in load_drives(drives))
    rc("enroll", "--fleet", root / "fleet", "--vehicles", 4, "--fleet-id", "t", "--min-speed", repr(vmin), "--tls")
    rc("enroll", "--fleet", root / "other", "--vehicles", 1, "--fleet-id", "t", "--tls")
    return root, drives


@pytest.mark.parametrize("kind", BROKERS)
def test_only_tls_clients_that_trust_the_fleet_ca_connect(world, tmp_path, kind):
    root, _ = world
    port = free_port()
    p = (start_amqtt(root / "fleet", port, tmp_path / "b.log") if kind == "amqtt"
         else start_mosquitto(root / "fleet", port, tmp_path / "mosq", tmp_path / "b.log"))
    try:
        v1 = load_login(root / "fleet" / "vehicles" / "v1" / "broker.toml")
        svc = load_login(root / "fleet" / "service" / "broker.toml")
        a = MqttClient(f"mqtts://127.0.0.1:{port}", svc, "rc-tls-svc").connect(timeout=20)
        b = MqttClient(f"mqtts://127.0.0.1:{port}", v1, "rc-tls-v1").connect(timeout=20)
        a.subscribe("rc/t/v/+/#")
        time.sleep(0.5)
        b.publish("rc/t/v/v1/hello", b"over TLS")
        got = a.receive(10)
        a.close()
        b.close()
        assert got == ("rc/t/v/v1/hello", b"over TLS")
        with pytest.raises(ParameterError, match="no connection"):          # no TLS on a TLS-only port
            MqttClient(f"mqtt://127.0.0.1:{port}", v1, "rc-tls-plain").connect(timeout=5)
        other = load_login(root / "other" / "vehicles" / "v1" / "broker.toml")
        with pytest.raises(ParameterError, match="fleet's certificate"):    # trusts another fleet's CA
            MqttClient(f"mqtts://127.0.0.1:{port}", replace(v1, ca_file=other.ca_file), "rc-tls-ca").connect(timeout=5)
        with pytest.raises(ParameterError, match="fleet's certificate"):    # a name the certificate lacks
            MqttClient(f"mqtts://127.0.0.2:{port}", v1, "rc-tls-name").connect(timeout=5)
        with pytest.raises(ParameterError, match="TLS needs the fleet CA"):
            MqttClient(f"mqtts://127.0.0.1:{port}", replace(v1, ca_file=None), "rc-tls-noca")
    finally:
        stop(p)


def test_a_whole_run_over_tls_equals_estimate(world, tmp_path):
    root, drives = world
    rc("estimate", *sum((["--drive", d] for d in drives), []), "--out", tmp_path / "estimate")
    port = free_port()
    serve = start_serve(root / "fleet", tmp_path / "s.sqlite", tmp_path / "serve.log", listen=port)
    try:
        assert f"mqtts://127.0.0.1:{port}" in (tmp_path / "serve.log").read_text()
        out = rc("fleet", "--fleet", root / "fleet", *sum((["--drive", d] for d in drives), []), "--broker",
                 f"mqtts://127.0.0.1:{port}", "--timeout", 120, timeout=300)
    finally:
        assert stop(serve) == 0
    assert "4 of 4 vehicles done" in out.stdout
    rc("export", "--store", tmp_path / "s.sqlite", "--out", tmp_path / "out")
    assert assert_same_table(tmp_path / "estimate" / "final_estimate.csv", tmp_path / "out" / "final_estimate.csv") <= 1e-9
