"""Validated, phased secure aggregation between separate parties as messages (issue 20, section 2).

Oracles: the networked session's result equals the in-process ``run_phased_session`` on the same inputs
(bit for bit: the same fixed-point sums); a vehicle whose proof fails is named and the round goes on
without it (phase 1) or aborts with nothing after phase 1 revealed (later phases); a leader that
equivocates, replays or substitutes keys gets nothing from the helper or the vehicles; the helper's
release log holds across a restart.
"""

from __future__ import annotations


import numpy as np
import pytest

from roadcollab.errors import MessageError
from roadcollab.network.prioagent import PrioAgent, run_prio_session
from roadcollab.network.priohelper import PrioHelperService
from roadcollab.network.prioround import PrioLeader, PrioParams
from roadcollab.network.messages import seal
from roadcollab.network.priowire import AggregatorKeys, key_topic, pack, unpack
from roadcollab.network.relaykey import RelayKey
from roadcollab.privacy.secagg_active_run import SecAggFleet
from roadcollab.privacy.secagg_flp import ValidityEncoding
from roadcollab.privacy.secagg_messages import SecAggSpec, session_id
from roadcollab.privacy.secagg_phased import run_phased_session
from roadcollab.privacy.secagg_store import ReleaseLog, SessionLedger
from roadcollab.wire.identity import FleetAuthority, VehicleIdentity

L = 12
PREFIX = "rc/t"


def _world(n=5, phases=3, R=0.6, seed=0, helper_log=None):
    auth = FleetAuthority.generate("t")
    trust = auth.trust()
    wide = ValidityEncoding(np.full(L, 4.0), 2.0 ** -12)
    tight = ValidityEncoding(np.full(L, R), 2.0 ** -12, norm=R)
    params = PrioParams(wide, (tight,) * (phases - 1), min_inputs=3)
    ka = AggregatorKeys(VehicleIdentity.enroll(auth, params.leader_id), RelayKey.generate())
    kb = AggregatorKeys(VehicleIdentity.enroll(auth, params.helper_id), RelayKey.generate())
    gen = np.random.default_rng(seed)
    road = gen.normal(0, 1.0, L)
    inputs = {f"v{i}": road + gen.normal(0, 0.08, L) for i in range(1, n + 1)}
    agents = {v: PrioAgent(VehicleIdentity.enroll(auth, v), trust, params, SessionLedger(), PREFIX, {7: u},
                           rng=np.random.default_rng(i)) for i, (v, u) in enumerate(inputs.items())}
    helper = PrioHelperService(PREFIX, params, trust, kb, ka.advert(PREFIX), helper_log or ReleaseLog())
    return dict(auth=auth, trust=trust, params=params, ka=ka, kb=kb, inputs=inputs, agents=agents, helper=helper,
                wide=wide, tight=tight)


def _leader(w, epoch=0, log=None):
    return PrioLeader(PREFIX, 7, epoch, w["params"], w["trust"], w["ka"], w["kb"].advert(PREFIX), log or ReleaseLog())


def test_networked_session_equals_the_in_process_one_bit_for_bit():
    w = _world()
    leader = _leader(w)
    broker = run_prio_session(leader, w["helper"], w["agents"], list(w["agents"]))
    assert leader.state == "finished", leader.events
    assert leader.accepted == (1, 2, 3, 4, 5) and leader.refused == {}
    fleet = SecAggFleet(5, SecAggSpec(min_inputs=3, threshold=3))
    ref = run_phased_session(fleet, {i + 1: u for i, u in enumerate(w["inputs"].values())}, session_id(7, 0),
                             w["wide"], w["tight"], phases=3, verify_key=bytes(32), rng=0)
    assert np.array_equal(leader.result, ref.result)
    assert np.max(np.abs(leader.result - np.mean(list(w["inputs"].values()), axis=0))) < 3 * 2.0 ** -12
    assert all(a.closed == {(7, 0): "finished"} for a in w["agents"].values())
    assert broker.bytes_published > 0


def _mean(w, vids):
    return np.mean([w["inputs"][v] for v in vids], axis=0)


def _cheat(monkeypatch, vehicle, phase, w):
    """Vehicle ``vehicle`` sends, in ``phase``, a value far outside the phase's bound with a proof made for it."""
    import roadcollab.network.prioagent as agent_mod
    from roadcollab.privacy.secagg_phased import phase_session
    honest = agent_mod.submit

    def fake(enc, x, session, pid, rng, *, identity=None):
        if identity.vehicle_id == vehicle and session == phase_session(session_id(7, 0), phase):
            q = np.full(enc.length, 2 ** int(enc.bits[0]) - 1)     # every coordinate at +B: outside the norm ball
            if phase == 1:
                q = np.full(enc.length, 2 ** 40)                    # not the sum of its bits
            return honest(enc, None, session, pid, rng, x=enc.encode_raw(q), identity=identity)
        return honest(enc, x, session, pid, rng, identity=identity)
    monkeypatch.setattr(agent_mod, "submit", fake)


def test_a_phase_one_cheater_is_named_and_the_session_goes_on_without_it(monkeypatch):
    w = _world()
    _cheat(monkeypatch, "v3", 1, w)
    leader = _leader(w)
    run_prio_session(leader, w["helper"], w["agents"], list(w["agents"]))
    assert leader.state == "finished" and leader.accepted == (1, 2, 4, 5)
    assert set(leader.refused) == {3} and "vehicle 3" in leader.refused[3]
    assert np.max(np.abs(leader.result - _mean(w, ["v1", "v2", "v4", "v5"]))) < 3 * 2.0 ** -12


def test_a_later_phase_cheater_aborts_the_session_and_nothing_after_phase_one_is_revealed(monkeypatch):
    w = _world()
    _cheat(monkeypatch, "v3", 2, w)
    leader = _leader(w)
    run_prio_session(leader, w["helper"], w["agents"], list(w["agents"]))
    assert leader.state == "aborted" and leader.result is None and leader.phase == 2
    assert "circuit output" in leader.refused[3] and set(leader.refused) == {3}
    helper = w["helper"].session((7, 0))
    assert [e for e in helper.events if e[0] == "released"] == [("released", "phase 1 over 5 vehicles")]


def test_an_offline_vehicle_is_left_out_in_phase_one_and_aborts_a_later_phase():
    w = _world()
    leader = _leader(w)
    run_prio_session(leader, w["helper"], w["agents"], list(w["agents"]), offline=["v2"])
    assert leader.state == "finished" and leader.accepted == (1, 3, 4, 5)
    assert np.max(np.abs(leader.result - _mean(w, ["v1", "v3", "v4", "v5"]))) < 3 * 2.0 ** -12
    w = _world()
    leader = _leader(w)
    gone = w["agents"]["v2"]
    answer = gone._answer
    gone._answer = lambda key, k, h, blobs: answer(key, k, h, blobs) if k == 1 else []   # leaves after phase 1
    run_prio_session(leader, w["helper"], w["agents"], list(w["agents"]))
    assert leader.state == "aborted" and leader.result is None and 2 in leader.refused


def test_a_second_session_on_the_measurement_gets_nothing_from_the_vehicles():
    """Differencing: a session with every vehicle, then one without the victim on the same segment."""
    w = _world()
    run_prio_session(_leader(w), w["helper"], w["agents"], list(w["agents"]))
    second = _leader(w, epoch=1)
    run_prio_session(second, w["helper"], w["agents"], ["v1", "v2", "v3", "v4"])
    assert second.state == "aborted" and second.result is None
    again = _leader(w, epoch=0)           # the same (segment, epoch) relabelled as a new session
    run_prio_session(again, w["helper"], w["agents"], ["v1", "v2", "v3", "v4"])
    assert again.result is None
    assert all(any("already contributed" in r for r in w["agents"][v].refusals) for v in ["v1", "v2", "v3", "v4"])


def test_the_helper_releases_once_per_phase_also_after_a_restart(tmp_path):
    log = tmp_path / "helper_releases.sqlite"
    w = _world(helper_log=ReleaseLog(log))
    leader = _leader(w)
    broker_msgs = []
    helper = w["helper"]
    record = helper.handle

    def spy(topic, payload):
        broker_msgs.append((topic, payload))
        return record(topic, payload)
    helper.handle = spy
    run_prio_session(leader, helper, w["agents"], list(w["agents"]))
    assert leader.state == "finished"
    helper.log.close()
    restarted = PrioHelperService(PREFIX, w["params"], w["trust"], w["kb"], w["ka"].advert(PREFIX), ReleaseLog(log))
    out = [p for t, pl in broker_msgs for p in restarted.handle(t, pl)]
    assert not any(b"result" in p.payload[:200] for p in out)          # no sum share released again
    events = restarted.session((7, 0)).events
    assert any("already released" in r for k, r in events if k == "refused")


def test_a_leader_cannot_substitute_the_helpers_key_or_show_vehicles_another_set():
    w = _world()
    fake_helper = AggregatorKeys(VehicleIdentity.enroll(w["auth"], "v9"), RelayKey.generate())
    # the leader's own key, signed by the leader for the helper's key topic
    substituted = seal(w["ka"].identity, key_topic(PREFIX, "aggregator-b"), w["ka"].key.public)
    with pytest.raises(MessageError, match="signed by 'aggregator-a'"):
        PrioLeader(PREFIX, 7, 0, w["params"], w["trust"], w["ka"], substituted, ReleaseLog())
    agent = w["agents"]["v1"]
    for advert in (substituted, fake_helper.advert(PREFIX), w["ka"].advert(PREFIX)):
        bad_invite = pack({"t": "invite", "phase": 1, "id": 1, "roster": [1, 2, 3]}, advert, b"")
        assert agent.on_message(f"{PREFIX}/prio/7/0/to/v1", bad_invite) == []
        assert "signed by" in agent.refusals[-1] or "bad signature" in agent.refusals[-1]
    assert not agent.ledger.contributed(session_id(7, 0))      # nothing recorded, nothing sent
    # a genuine run, then the phase-2 invite with the signed result's set changed
    leader = _leader(w)
    invites = []
    handle = leader.handle

    def spy(topic, payload):
        out = handle(topic, payload)
        invites.extend(p for p in out if p.topic.endswith("/to/v1") and unpack(p.payload, "x")[0].get("phase") == 2)
        return out
    leader.handle = spy
    run_prio_session(leader, w["helper"], w["agents"], list(w["agents"]))
    h, blobs = unpack(invites[0].payload, "invite")
    rh, rb = unpack(blobs[1], "result")
    forged = pack(h, blobs[0], pack(dict(rh, accepted=[1, 2, 3]), *rb))
    fresh = PrioAgent(agent.identity, w["trust"], w["params"], SessionLedger(), PREFIX, {7: w["inputs"]["v1"]})
    fresh._u[(7, 0)] = w["params"].wide.clip(w["inputs"]["v1"])[0]
    assert fresh.on_message(invites[0].topic, forged) == []
    assert "does not verify" in fresh.refusals[-1] or "signature" in fresh.refusals[-1]


def test_the_helper_refuses_a_roster_with_an_aggregator_as_a_vehicle():
    """The leader's own certificate in the roster is a Sybil whose input it knows: with k = 2 the session's
    mean would give the victim's input away. Found by attacking the fleet mode, where the service holds
    ``aggregator-a``'s identity."""
    w = _world(n=1)
    params = PrioParams(w["wide"], (w["tight"],) * 2, min_inputs=2)
    helper = PrioHelperService(PREFIX, params, w["trust"], w["kb"], w["ka"].advert(PREFIX), ReleaseLog())
    sybil = PrioAgent(w["ka"].identity, w["trust"], params, SessionLedger(), PREFIX, {7: np.zeros(L)},
                      rng=np.random.default_rng(9))
    victim = PrioAgent(w["agents"]["v1"].identity, w["trust"], params, SessionLedger(), PREFIX, {7: w["inputs"]["v1"]},
                       rng=np.random.default_rng(8))
    leader = PrioLeader(PREFIX, 7, 0, params, w["trust"], w["ka"], w["kb"].advert(PREFIX), ReleaseLog())
    run_prio_session(leader, helper, {"v1": victim, "aggregator-a": sybil}, ["v1", "aggregator-a"])
    assert leader.result is None and leader.state == "aborted"
    assert any("aggregator id 'aggregator-a'" in r for k, r in helper.session((7, 0)).events if k == "refused")
    assert helper.log.released(session_id(7, 0), 1) is None


def test_no_message_raises_out_of_any_party():
    w = _world()
    leader = _leader(w)
    leader.open(list(w["agents"]))
    rng = np.random.default_rng(3)
    junk = [b"", b"\x00" * 3, rng.bytes(64), pack({"t": "invite", "phase": 1}), pack({"t": "accept", "phase": 1}),
            pack({"blobs": [10]}), b"\xff\xff\xff\x7f" + b"{}"]
    base = leader.topics.base
    for payload in junk:
        assert leader.handle(f"{base}/up/v1", payload) == []
        assert leader.handle(f"{base}/helper", payload) == []
        assert w["helper"].handle(f"{base}/leader", payload) == []
        assert w["agents"]["v1"].on_message(f"{base}/to/v1", payload) == []
    assert len(leader.events) == 2 * len(junk)


def test_parameters_file_round_trip_and_bad_input_lines(tmp_path, capsys):
    import json

    from roadcollab.network.prio_mqtt import main, params_from_dict, params_to_dict
    w = _world()
    back, prefix = params_from_dict(json.loads(json.dumps(params_to_dict(w["params"], PREFIX))), "p.json")
    assert prefix == PREFIX and back.phases == 3 and back.min_inputs == 3
    assert np.array_equal(back.wide.bounds, w["wide"].bounds) and back.tight[0].norm == w["tight"].norm
    bad = tmp_path / "p.json"
    bad.write_text(json.dumps({"prefix": PREFIX, "wide": {"bounds": [1.0]}}))
    args = ["helper", "--folder", str(tmp_path), "--broker", "mqtt://127.0.0.1:1", "--params", str(bad), "--segment", "0"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "p.json" in err[0] and "not validated-session parameters" in err[0]
    (tmp_path / "result.json").write_text("{}")
    assert main(["leader", *args[1:]]) == 2
    assert "result.json exists" in capsys.readouterr().err
    assert (tmp_path / "result.json").read_text() == "{}"


@pytest.mark.xfail(strict=True, reason="known gap (docs/security-secagg.md, 'A deviating aggregator steers the centres'): "
                                       "B cannot check A's sum share, so A chooses the helper-signed m_k")
def test_a_deviating_leader_cannot_steer_the_centre_the_vehicles_clip_around():
    """Found by attacking the fleet mode. A adds an offset to its phase-1 sum share: B signs the shifted
    ``m_1`` and every vehicle clips its phase-2 deviation around A's chosen point; with three such queries A
    recovered two honest inputs to l2 error 0.004 where the mean alone gives 0.053. The property asserted here
    (some party refuses the steered centre) does not hold today."""
    from roadcollab.network.prioround import PrioLeader as Base

    w = _world()
    shift = np.full(L, 1.0)                           # a centre 1 m off in every value, inside the 4 m box

    class Steering(Base):
        def _accept(self):
            out = super()._accept()
            if self._pending is not None and self.phase == 1:
                acc, share = self._pending
                enc = self.params.encoding(1)
                delta = np.rint(shift * len(acc) / enc.scale).astype(np.int64)
                share = (share + np.array([int(x) for x in delta], dtype=object)) % enc.field.p
                self._pending = (acc, share)
                out = [self._to_helper({"t": "accept", "phase": 1, "accepted": list(acc)}, enc.field.to_bytes(share))]
            return out

    leader = Steering(PREFIX, 7, 0, w["params"], w["trust"], w["ka"], w["kb"].advert(PREFIX), ReleaseLog())
    run_prio_session(leader, w["helper"], w["agents"], list(w["agents"]))
    refused = [r for a in w["agents"].values() for r in a.refusals] + [r for k, r in leader.events if k == "aborted"]
    assert refused, f"the session {leader.state} around a centre A moved by {shift[0]} m in every value"


def _opened(w, helper, epoch):
    """Feed the helper a new leader's ``open`` for session (7, epoch)."""
    leader = _leader(w, epoch=epoch)
    return [p for m in leader.open(list(w["agents"])) if m.topic.endswith("/leader") for p in helper.handle(m.topic, m.payload)]


def test_a_finished_session_leaves_the_helper_its_state_dropped_and_a_replay_gets_nothing():
    # A long-running helper kept every session's per-vehicle state for ever (noticed in issue 20's review).
    w = _world()
    leader, helper = _leader(w), w["helper"]
    seen, handle = [], helper.handle
    helper.handle = lambda t, p: seen.append((t, p)) or handle(t, p)
    run_prio_session(leader, helper, w["agents"], list(w["agents"]))
    assert leader.state == "finished" and helper.sessions == {}
    why, done = helper.finished[(7, 0)]
    assert why == "finished" and done.finished and not done._own and not done._peer
    assert [e for e in done.events if e[0] == "released"][-1] == ("released", "phase 3 over 5 vehicles")
    assert seen and not [out for t, p in seen for out in handle(t, p)]
    assert helper.sessions == {}


def test_the_helper_refuses_sessions_beyond_its_open_limit_and_ends_idle_ones():
    w = _world()
    now = [0.0]
    helper = PrioHelperService(PREFIX, w["params"], w["trust"], w["kb"], w["ka"].advert(PREFIX), ReleaseLog(),
                               max_open=2, max_idle_s=60.0, clock=lambda: now[0])
    for epoch in range(3):
        _opened(w, helper, epoch)
    assert sorted(helper.sessions) == [(7, 0), (7, 1)]
    assert helper.refused == ["session 7/2 refused: 2 sessions are open"]
    now[0] = 50.0
    bad = seal(w["ka"].identity, f"{PREFIX}/prio/7/0/leader", pack({"t": "bogus"}))
    assert helper.handle(f"{PREFIX}/prio/7/0/leader", bad) == []     # refused: keeps the session no longer alive
    now[0] = 61.0
    assert sorted(helper.expire()) == [(7, 0), (7, 1)]
    assert helper.sessions == {} and helper.finished[(7, 0)][0] == "idle"
    assert helper.finished[(7, 0)][1].roster == {}
    assert _opened(w, helper, 0) == [] and (7, 0) not in helper.sessions      # an ended session stays ended
    _opened(w, helper, 2)
    assert list(helper.sessions) == [(7, 2)]                                   # room again for a new one


def test_only_the_leaders_signed_message_on_the_canonical_topic_creates_a_helper_session():
    w = _world()
    helper = w["helper"]
    assert PrioHelperService.__init__.__kwdefaults__["max_open"] is None     # a dropped session spends measurements
    leader = _leader(w, epoch=0)
    opening = next(m for m in leader.open(list(w["agents"])) if m.topic.endswith("/leader"))
    forged = seal(w["kb"].identity, opening.topic, pack({"t": "open", "roster": {"v1": 1}}))
    helper.handle(opening.topic, forged)                                        # signed, but not by the leader
    helper.handle(opening.topic.replace("/prio/7/", "/prio/07/"), opening.payload)   # another topic, same key
    helper.handle(opening.topic, b"not a signed message")
    assert helper.sessions == {}
    helper.handle(opening.topic, opening.payload)
    assert list(helper.sessions) == [(7, 0)] and helper.sessions[(7, 0)].roster
