"""The network commands in-process: enroll, status, export (the MQTT runs are in test_network_mqtt.py)."""

import stat

import pytest

from netkit import assert_same_table, write_drives
from roadcollab.cli.main import main
from roadcollab.io.drives import load_drives
from roadcollab.network.fleetdir import load_login, load_plan
from roadcollab.network.memory import run_in_memory
from roadcollab.network.store import ServiceStore


def test_enroll_writes_a_fleet_and_never_replaces_one(tmp_path, capsys):
    fleet = tmp_path / "fleet"
    assert main(["enroll", "--fleet", str(fleet), "--vehicles", "3", "--min-speed", "12"]) == 0
    assert "3 vehicles (v1..v3)" in capsys.readouterr().out
    assert load_plan(fleet).band_low_per_m == 0.5 / 12
    login = load_login(fleet / "vehicles" / "v2" / "broker.toml")
    assert login.username == "v2" and len(login.password) >= 24
    for f in ("vehicles/v2/broker.toml", "vehicles/v2/identity.key", "broker/mosquitto_passwd", "broker/amqtt_passwd"):
        assert stat.S_IMODE((fleet / f).stat().st_mode) == 0o600, f
    acl = (fleet / "broker" / "mosquitto_acl").read_text()
    assert ("user v2\ntopic write rc/fleet/v/v2/#\ntopic write rc/fleet/secagg/+/+/+/v2\n"
            "topic read rc/fleet/ack/v2\ntopic read rc/fleet/seg/+/waiting\ntopic read rc/fleet/secagg/+/+/to/v2\n") in acl
    key = (fleet / "authority" / "authority.key").read_bytes()
    assert main(["enroll", "--fleet", str(fleet), "--vehicles", "3"]) == 2
    assert "already holds a fleet" in capsys.readouterr().err
    assert (fleet / "authority" / "authority.key").read_bytes() == key


def test_enroll_validated_writes_one_folder_per_helper_and_their_topics(tmp_path, capsys):
    from roadcollab.network.fleetdir import load_aggregation

    fleet = tmp_path / "fleet"
    args = ["--vehicles", "4", "--aggregation", "validated", "--min-inputs", "3", "--round-size", "4", "--clip", "0.2"]
    assert main(["enroll", "--fleet", str(fleet), *args]) == 0
    out = capsys.readouterr().out
    assert "3 aggregators" in out and f"{fleet}/helper and {fleet}/helper-c" in out and "note:" not in out
    assert load_aggregation(fleet).aggregators == 3
    for name, cert in (("helper", "aggregator-b"), ("helper-c", "aggregator-c")):
        assert load_login(fleet / name / "broker.toml").username == cert
        assert (fleet / name / "x25519.key").is_file() and (fleet / name / "fleet.toml").is_file()
    acl = (fleet / "broker" / "mosquitto_acl").read_text()
    assert ("user aggregator-c\ntopic write rc/fleet/prio/+/+/agg/aggregator-c\ntopic write rc/fleet/prio/key/aggregator-c\n"
            "topic read rc/fleet/prio/+/+/agg/+\ntopic read rc/fleet/prio/+/+/fwd/aggregator-c\n") in acl
    two = tmp_path / "two"
    assert main(["enroll", "--fleet", str(two), *args, "--aggregators", "2"]) == 0
    out = capsys.readouterr().out
    assert "2 aggregators" in out and "note: with 2 aggregators, privacy of the later phases" in out
    assert (two / "helper").is_dir() and not (two / "helper-c").exists()
    assert "aggregator-c" not in (two / "broker" / "mosquitto_acl").read_text()


@pytest.mark.parametrize("args, msg", [
    (["--vehicles", "0"], "argument --vehicles: expected a number of vehicles from 1 to 1,000, got 0"),
    (["--vehicles", "2", "--fleet-id", "a/b"], "--fleet-id must be 1-64 characters"),
    (["--vehicles", "2", "--segment-length", "0.5"], "argument --segment-length: expected a segment length from 1"),
    (["--vehicles", "2", "--segment-length", "1.01"], "segment_length must be a whole number"),
    (["--vehicles", "2", "--aggregators", "4"], "argument --aggregators: expected a number of aggregators from 2 to 3, got 4"),
])
def test_enroll_bad_input_is_one_line(tmp_path, capsys, args, msg):
    try:
        code = main(["enroll", "--fleet", str(tmp_path / "f"), *args])
    except SystemExit as exc:  # refused while parsing
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert msg in err and err.count("\n") == 1


@pytest.mark.slow  # 8 s: a served fleet end to end
def test_status_and_export_of_a_store(tmp_path, capsys):
    paths, _ = write_drives(tmp_path / "drives", speeds=(12.0, 15.0))
    from roadcollab.io.drive_clean import clean_drive
    from roadcollab.network.plan import RoadPlan

    drives = [clean_drive(d)[0] for d in load_drives(paths)]   # as `vehicle` and `estimate` clean them

    plan = RoadPlan(fleet_id="t", min_speed=min(float(d.speeds().min()) for d in drives))
    run_in_memory(drives, plan, store=ServiceStore(tmp_path / "s.sqlite", plan))
    assert main(["status", "--store", str(tmp_path / "s.sqlite")]) == 0
    assert "2 vehicles seen, 6 segments with a fused estimate, 12 contributions" in capsys.readouterr().out
    assert main(["export", "--store", str(tmp_path / "s.sqlite"), "--out", str(tmp_path / "net")]) == 0
    assert main(["estimate", "--drive", paths[0], "--drive", paths[1], "--out", str(tmp_path / "est")]) == 0
    for f in ("final_estimate.csv", "road_estimates.csv", "iri.csv"):
        assert_same_table(tmp_path / "est" / f, tmp_path / "net" / f, rtol=0.0)
    assert (tmp_path / "est" / "anomalies.csv").read_text() == (tmp_path / "net" / "anomalies.csv").read_text()
    (tmp_path / "junk.sqlite").write_bytes(b"not a database" * 100)
    assert main(["status", "--store", str(tmp_path / "junk.sqlite")]) == 2
    assert "not a roadcollab service store" in capsys.readouterr().err
    assert (tmp_path / "junk.sqlite").read_bytes() == b"not a database" * 100


def test_enroll_tls_writes_a_fleet_ca_and_a_broker_certificate(tmp_path, capsys):
    from cryptography import x509

    from roadcollab.network.brokers import amqtt_config, mosquitto_config

    fleet = tmp_path / "fleet"
    assert main(["enroll", "--fleet", str(fleet), "--vehicles", "2", "--tls", "--tls-host", "rsu.example",
                 "--tls-host", "10.0.0.7"]) == 0
    assert "TLS" in capsys.readouterr().out
    ca = x509.load_pem_x509_certificate((fleet / "broker" / "ca.pem").read_bytes())
    cert = x509.load_pem_x509_certificate((fleet / "broker" / "server.pem").read_bytes())
    cert.verify_directly_issued_by(ca)
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert set(map(str, san.get_values_for_type(x509.IPAddress))) == {"127.0.0.1", "10.0.0.7"}
    assert set(san.get_values_for_type(x509.DNSName)) == {"localhost", "rsu.example"}
    for f in ("broker/server.key", "authority/tls-ca.key"):
        assert stat.S_IMODE((fleet / f).stat().st_mode) == 0o600, f
    login = load_login(fleet / "vehicles" / "v2" / "broker.toml")
    assert login.ca_file.read_bytes() == (fleet / "broker" / "ca.pem").read_bytes()
    assert amqtt_config(fleet, "127.0.0.1", 8883)["listeners"]["default"]["ssl"] is True
    conf = mosquitto_config(fleet, "127.0.0.1", 8883, tmp_path / "mosq").read_text()
    assert "certfile" in conf and "keyfile" in conf and "tls_version tlsv1.2" in conf
    assert main(["enroll", "--fleet", str(tmp_path / "g"), "--vehicles", "1", "--tls-host", "x"]) == 2
    assert "--tls-host: needs --tls" in capsys.readouterr().err


def test_serve_status_lines_and_live_status(capsys):
    """``serve``'s event printer: off a terminal each line carries the counts; on one the counts live in a
    status line rich keeps current below the event lines."""
    import io

    from rich.console import Console

    from roadcollab.cli._service_status import ServiceStatus

    st = {"vehicles": 3, "segments": 2, "contributions": 7, "refused": {"bad": 1, "late": 2},
          "rounds": {"finished": 4, "open": 1}}
    plain = ServiceStatus(secure=True, console=Console(file=io.StringIO(), force_terminal=False))
    plain.event("segment 1: accepted v3", st)
    assert capsys.readouterr().out == ("segment 1: accepted v3  [3 vehicles, 2 segments, 7 contributions, rounds 4 "
                                       "finished/1 open/0 aborted, 3 refused]\n")
    buf = io.StringIO()
    live = ServiceStatus(secure=False, console=Console(file=buf, force_terminal=True, width=120))
    live.event("hello from v1", st)
    live.live.refresh()
    live.stop()
    out = buf.getvalue()
    assert "hello from v1" in out and "serving: 3 vehicles, 2 segments, 7 contributions, 3 refused" in out
    assert "rounds" not in out and live.live is None


def test_a_process_started_by_the_tests_stops_when_the_test_process_dies(tmp_path):
    """A test run killed by hand (SIGKILL: no fixture runs) leaves no server behind: the child of netkit.start
    gets SIGTERM from the kernel when its parent dies."""
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    here = Path(__file__).resolve().parent
    parent = subprocess.Popen([sys.executable, "-c", (
        f"import sys, time; sys.path.insert(0, {str(here)!r}); import netkit\n"
        f"p = netkit.start(sys.executable, '-c', 'import time; time.sleep(120)', log=__import__('pathlib').Path("
        f"{str(tmp_path / 'child.log')!r}))\n"
        "print(p.pid, flush=True); time.sleep(120)\n")], stdout=subprocess.PIPE, text=True)
    try:
        child = int(parent.stdout.readline())
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=10)
        end = time.monotonic() + 10
        while time.monotonic() < end and Path(f"/proc/{child}").exists() and \
                Path(f"/proc/{child}/stat").read_text().split()[2] != "Z":
            time.sleep(0.05)
        alive = Path(f"/proc/{child}").exists() and Path(f"/proc/{child}/stat").read_text().split()[2] != "Z"
        if alive:
            os.kill(child, signal.SIGKILL)
        assert not alive, "the child outlived its parent"
    finally:
        parent.kill()
        parent.wait(timeout=10)
        parent.stdout.close()
