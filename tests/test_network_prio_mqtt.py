"""Validated, phased sessions with every party its own process over a real broker on 127.0.0.1 (issue 20).

The leader, the two helpers and each vehicle run ``python -m roadcollab.network.prio_mqtt`` with their own
login, under the broker's ACL; the leader finds the helpers' key adverts on the broker. Oracles: the
leader's result equals the in-process ``run_phased_session`` on the same inputs bit for bit; a rostered
vehicle that never starts is left out at the leader's timeout and the session completes with ``k``; the
helpers' release logs and the vehicles' ledgers are on disk afterwards.
"""

from __future__ import annotations

import json
import secrets

import numpy as np
import pytest
from netkit import HAVE_MOSQUITTO, PY, free_port, start, start_amqtt, start_mosquitto, stop

from roadcollab.network.fleetdir import acl_rules, write_broker
from roadcollab.network.prio_mqtt import params_to_dict
from roadcollab.network.prioround import PrioParams
from roadcollab.network.relaykey import RelayKey
from roadcollab.privacy.secagg_active_run import SecAggFleet
from roadcollab.privacy.secagg_flp import ValidityEncoding
from roadcollab.privacy.secagg_messages import SecAggSpec, session_id
from roadcollab.privacy.secagg_phased import run_phased_session
from roadcollab.privacy.secagg_store import SessionLedger
from roadcollab.wire.identity import FleetAuthority, VehicleIdentity

pytestmark = pytest.mark.slow

BROKERS = ["amqtt", pytest.param("mosquitto", marks=pytest.mark.skipif(not HAVE_MOSQUITTO,
                                                                        reason="apt-get install -y mosquitto"))]
L = 32


def _world(root, n=4):
    auth = FleetAuthority.generate("t")
    wide = ValidityEncoding(np.full(L, 4.0), 2.0 ** -12)
    tight = ValidityEncoding(np.full(L, 0.8), 2.0 ** -12, norm=0.8)
    params = PrioParams(wide, (tight, tight), min_inputs=3)
    (root / "params.json").write_text(json.dumps(params_to_dict(params, "rc/t")))
    vids = [f"v{i}" for i in range(1, n + 1)]
    users = {"service": ("leader", params.leader_id), **{h: (h, h) for h in params.helper_ids},
             **{v: (v, v) for v in vids}}
    gen = np.random.default_rng(0)
    road = gen.normal(0, 1.0, L)
    inputs = {}
    logins = {}
    for user, (name, cert_id) in users.items():
        d = root / name
        VehicleIdentity.enroll(auth, cert_id).save(d)
        auth.trust().save(d / "trust.toml")
        logins[user] = secrets.token_urlsafe(16)
        (d / "broker.toml").write_text(f'username = "{user}"\npassword = "{logins[user]}"\n')
        if name == "leader" or name in params.helper_ids:
            RelayKey.generate().save(d / "x25519.key")
        else:
            inputs[name] = road + gen.normal(0, 0.08, L)
            np.save(d / "input.npy", inputs[name])
    write_broker(root / "broker", logins, acl_rules("t", vids, helpers=params.helper_ids))
    return params, inputs, vids


@pytest.mark.parametrize("broker", BROKERS)
def test_every_party_a_process_over_the_broker(tmp_path, broker):
    params, inputs, vids = _world(tmp_path)
    port = free_port()
    b = (start_amqtt(tmp_path, port, tmp_path / "broker.log") if broker == "amqtt"
         else start_mosquitto(tmp_path, port, tmp_path / "mosq", tmp_path / "broker.log"))
    url = f"mqtt://127.0.0.1:{port}"

    def party(role, name, *extra):
        return start(PY, "-m", "roadcollab.network.prio_mqtt", role, "--folder", tmp_path / name, "--broker", url,
                     "--params", tmp_path / "params.json", "--segment", 7, "--timeout", 120, *extra,
                     log=tmp_path / f"{name}.log")
    procs = []
    try:
        procs = [party("helper", h) for h in params.helper_ids] + [party("vehicle", v) for v in vids[:3]]
        leader = party("leader", "leader", "--roster", ",".join(vids), "--idle", 4)     # v4 never starts
        assert leader.wait(150) == 0, (tmp_path / "leader.log").read_text()
        for p in procs:
            assert p.wait(30) == 0, [(tmp_path / f"{n}.log").read_text() for n in (*params.helper_ids, *vids[:3])]
    finally:
        for p in procs:
            if p.poll() is None:
                stop(p)
        stop(b)
    out = json.loads((tmp_path / "leader" / "result.json").read_text())
    assert out["state"] == "finished" and out["accepted"] == [1, 2, 3] and list(out["refused"]) == ["4"]
    fleet = SecAggFleet(3, SecAggSpec(min_inputs=3, threshold=3))
    ref = run_phased_session(fleet, {i + 1: inputs[v] for i, v in enumerate(vids[:3])}, session_id(7, 0),
                             params.wide, params.tight, phases=3, verify_key=bytes(32), rng=0)
    assert np.array_equal(np.array(out["result"]), ref.result)
    for v in vids[:3]:
        led = SessionLedger(tmp_path / v / "ledger.sqlite")
        assert led.contributed(session_id(7, 0))
        led.close()
    for h in params.helper_ids:
        assert (tmp_path / h / "releases.sqlite").stat().st_size > 0
