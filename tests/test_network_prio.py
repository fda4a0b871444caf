"""Validated, phased secure aggregation between separate parties as messages (issue 20, section 2).

Oracles: the networked session's result equals the in-process ``run_phased_session`` on the same inputs
(bit for bit: the same fixed-point sums), with two and with three aggregators; a vehicle whose proof fails
is named and the session goes on without it (phase 1) or aborts with nothing after phase 1 revealed (later
phases); a leader that equivocates, replays or substitutes keys gets nothing from the helpers or the
vehicles; the release logs hold across a restart. With three aggregators, any one that deviates (a shifted
sum, a lie about a proof, another set, a coin that does not open its commitment) is caught before a vehicle
acts on what it did; with two, the shifted sum is not caught, which is why the fleet default is three.
"""

from __future__ import annotations

import numpy as np
import pytest

from roadcollab.errors import MessageError
from roadcollab.network.messages import seal
from roadcollab.network.prioagent import PrioAgent, run_prio_session
from roadcollab.network.priohelper import PrioHelperService
from roadcollab.network.prioround import PrioLeader, PrioParams
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
TWO, THREE = ("aggregator-b",), ("aggregator-b", "aggregator-c")


def _world(n=5, phases=3, R=0.6, seed=0, helpers=THREE, logs=None, min_inputs=3):
    auth = FleetAuthority.generate("t")
    trust = auth.trust()
    wide = ValidityEncoding(np.full(L, 4.0), 2.0 ** -12)
    tight = ValidityEncoding(np.full(L, R), 2.0 ** -12, norm=R)
    params = PrioParams(wide, (tight,) * (phases - 1), min_inputs=min_inputs, helper_ids=helpers)
    keys = {p: AggregatorKeys(VehicleIdentity.enroll(auth, p), RelayKey.generate()) for p in params.aggregators}
    gen = np.random.default_rng(seed)
    road = gen.normal(0, 1.0, L)
    inputs = {f"v{i}": road + gen.normal(0, 0.08, L) for i in range(1, n + 1)}
    agents = {v: PrioAgent(VehicleIdentity.enroll(auth, v), trust, params, SessionLedger(), PREFIX, {7: u},
                           rng=np.random.default_rng(i)) for i, (v, u) in enumerate(inputs.items())}
    logs = logs or {}
    helper_svcs = [PrioHelperService(PREFIX, params, trust, keys[h], logs.get(h) or ReleaseLog(),
                                     rng=np.random.default_rng(100 + j)) for j, h in enumerate(helpers)]
    return dict(auth=auth, trust=trust, params=params, keys=keys, ka=keys[params.leader_id], inputs=inputs,
                agents=agents, helpers=helper_svcs, wide=wide, tight=tight)


def _adverts(w):
    return [w["keys"][h].advert(PREFIX) for h in w["params"].helper_ids]


def _leader(w, epoch=0, log=None, cls=PrioLeader):
    return cls(PREFIX, 7, epoch, w["params"], w["trust"], w["ka"], _adverts(w), log or ReleaseLog(),
               rng=np.random.default_rng(99))


def _mean(w, vids):
    return np.mean([w["inputs"][v] for v in vids], axis=0)


def _in_process(w, aggregators):
    fleet = SecAggFleet(len(w["inputs"]), SecAggSpec(min_inputs=3, threshold=3))
    return run_phased_session(fleet, {i + 1: u for i, u in enumerate(w["inputs"].values())}, session_id(7, 0),
                              w["wide"], w["tight"], phases=3, verify_key=bytes(32), rng=0, aggregators=aggregators)


@pytest.mark.parametrize("helpers", [TWO, THREE])
def test_networked_session_equals_the_in_process_one_bit_for_bit(helpers):
    w = _world(helpers=helpers)
    leader = _leader(w)
    broker = run_prio_session(leader, w["helpers"], w["agents"], list(w["agents"]))
    assert leader.state == "finished", leader.events
    assert leader.accepted == (1, 2, 3, 4, 5) and leader.refused == {}
    for aggregators in (2, 3):
        assert np.array_equal(leader.result, _in_process(w, aggregators).result)
    assert np.max(np.abs(leader.result - np.mean(list(w["inputs"].values()), axis=0))) < 3 * 2.0 ** -12
    assert all(a.closed == {(7, 0): "finished"} for a in w["agents"].values())
    assert all(h.finished[(7, 0)][1].finished for h in w["helpers"])
    assert broker.bytes_published > 0


def _cheat(monkeypatch, vehicle, phase):
    """Vehicle ``vehicle`` sends, in ``phase``, a value far outside the phase's bound with a proof made for it."""
    import roadcollab.network.prioagent as agent_mod
    from roadcollab.privacy.secagg_phased import phase_session
    honest = agent_mod.submit

    def fake(enc, x, session, pid, rng, *, aggregators, identity=None):
        if identity.vehicle_id == vehicle and session == phase_session(session_id(7, 0), phase):
            q = np.full(enc.length, 2 ** int(enc.bits[0]) - 1)     # every coordinate at +B: outside the norm ball
            if phase == 1:
                q = np.full(enc.length, 2 ** 40)                    # not the sum of its bits
            return honest(enc, None, session, pid, rng, aggregators=aggregators, x=enc.encode_raw(q),
                          identity=identity)
        return honest(enc, x, session, pid, rng, aggregators=aggregators, identity=identity)
    monkeypatch.setattr(agent_mod, "submit", fake)


@pytest.mark.parametrize("helpers", [TWO, THREE])
def test_a_phase_one_cheater_is_named_and_the_session_goes_on_without_it(monkeypatch, helpers):
    w = _world(helpers=helpers)
    _cheat(monkeypatch, "v3", 1)
    leader = _leader(w)
    run_prio_session(leader, w["helpers"], w["agents"], list(w["agents"]))
    assert leader.state == "finished" and leader.accepted == (1, 2, 4, 5)
    assert set(leader.refused) == {3} and "vehicle 3" in leader.refused[3]
    assert np.max(np.abs(leader.result - _mean(w, ["v1", "v2", "v4", "v5"]))) < 3 * 2.0 ** -12


def test_a_later_phase_cheater_aborts_the_session_and_nothing_after_phase_one_is_revealed(monkeypatch):
    w = _world()
    _cheat(monkeypatch, "v3", 2)
    leader = _leader(w)
    run_prio_session(leader, w["helpers"], w["agents"], list(w["agents"]))
    assert leader.state == "aborted" and leader.result is None and leader.phase == 2
    assert "circuit output" in leader.refused[3] and set(leader.refused) == {3}
    for h in w["helpers"]:
        assert [e for e in h.finished[(7, 0)][1].events if e[0] == "released"] == [("released", "phase 1 over 5 vehicles")]


def test_an_offline_vehicle_is_left_out_in_phase_one_and_aborts_a_later_phase():
    w = _world()
    leader = _leader(w)
    run_prio_session(leader, w["helpers"], w["agents"], list(w["agents"]), offline=["v2"])
    assert leader.state == "finished" and leader.accepted == (1, 3, 4, 5)
    assert np.max(np.abs(leader.result - _mean(w, ["v1", "v3", "v4", "v5"]))) < 3 * 2.0 ** -12
    w = _world()
    leader = _leader(w)
    gone = w["agents"]["v2"]
    answer = gone._answer
    gone._answer = lambda key, k, h, blobs: answer(key, k, h, blobs) if k == 1 else []   # leaves after phase 1
    run_prio_session(leader, w["helpers"], w["agents"], list(w["agents"]))
    assert leader.state == "aborted" and leader.result is None and 2 in leader.refused


def test_a_second_session_on_the_measurement_gets_nothing_from_the_vehicles():
    """Differencing: a session with every vehicle, then one without the victim on the same segment."""
    w = _world()
    run_prio_session(_leader(w), w["helpers"], w["agents"], list(w["agents"]))
    second = _leader(w, epoch=1)
    run_prio_session(second, w["helpers"], w["agents"], ["v1", "v2", "v3", "v4"])
    assert second.state == "aborted" and second.result is None
    again = _leader(w, epoch=0)           # the same (segment, epoch) relabelled as a new session
    run_prio_session(again, w["helpers"], w["agents"], ["v1", "v2", "v3", "v4"])
    assert again.result is None
    assert all(any("already contributed" in r for r in w["agents"][v].refusals) for v in ["v1", "v2", "v3", "v4"])


def test_a_helper_tosses_one_coin_and_releases_once_per_phase_also_after_a_restart(tmp_path):
    """A replay of the vehicles' uploads to a helper restarted on its release log (found by a red team: the
    coin toss gave the replay a second query point of every proof, and two points give the input away) gets
    no coin, no verifier share and no sum."""
    path = tmp_path / "helper_releases.sqlite"
    w = _world(logs={"aggregator-b": ReleaseLog(path)})
    run_prio_session(_leader(w), w["helpers"], w["agents"], list(w["agents"]))
    w["helpers"][0].log.close()
    # The same measurement again, with vehicles and the other aggregators that forgot it (fresh ledgers and
    # logs): the helper restarted on its release log refuses to release phase 1 a second time.
    again = _world(logs={"aggregator-b": ReleaseLog(path)})
    again.update(auth=w["auth"], trust=w["trust"], keys=w["keys"], ka=w["ka"], params=w["params"])
    again["helpers"] = [PrioHelperService(PREFIX, w["params"], w["trust"], w["keys"][h], ReleaseLog(path) if j == 0
                                          else ReleaseLog()) for j, h in enumerate(w["params"].helper_ids)]
    again["agents"] = {v: PrioAgent(a.identity, w["trust"], w["params"], SessionLedger(), PREFIX, {7: w["inputs"][v]})
                       for v, a in w["agents"].items()}
    leader = _leader(again)
    run_prio_session(leader, again["helpers"], again["agents"], list(again["agents"]))
    assert leader.state == "aborted" and leader.result is None
    done = again["helpers"][0].session((7, 0))
    assert not any(k == "released" for k, _ in done.events)
    assert any(k == "aborted" and "coin of phase 1 of this session was already revealed" in r
               for k, r in done.events), done.events
    log = ReleaseLog(path)
    with pytest.raises(Exception, match="already released"):
        log.release(session_id(7, 0), 1, (1, 2, 3, 4, 5))
    with pytest.raises(Exception, match="already revealed"):
        log.coin(session_id(7, 0), 2)
    log.coin(session_id(7, 1), 1)                         # another measurement: its own coins


def test_a_leader_cannot_substitute_a_helpers_key_or_show_vehicles_another_set():
    w = _world()
    fake_helper = AggregatorKeys(VehicleIdentity.enroll(w["auth"], "v9"), RelayKey.generate())
    # the leader's own key, signed by the leader for a helper's key topic
    substituted = seal(w["ka"].identity, key_topic(PREFIX, "aggregator-b"), w["ka"].key.public)
    with pytest.raises(MessageError, match="signed by 'aggregator-a'"):
        PrioLeader(PREFIX, 7, 0, w["params"], w["trust"], w["ka"], [substituted, _adverts(w)[1]], ReleaseLog())
    agent = w["agents"]["v1"]
    for advert in (substituted, fake_helper.advert(PREFIX), w["ka"].advert(PREFIX)):
        bad_invite = pack({"t": "invite", "phase": 1, "id": 1, "roster": [1, 2, 3]}, w["ka"].advert(PREFIX), advert,
                          _adverts(w)[1], b"")
        assert agent.on_message(f"{PREFIX}/prio/7/0/to/v1", bad_invite) == []
        assert "signed by" in agent.refusals[-1] or "bad signature" in agent.refusals[-1]
    assert not agent.ledger.contributed(session_id(7, 0))      # nothing recorded, nothing sent
    # a genuine run, then the phase-2 invite with the signed result's set changed, or one signature dropped
    leader = _leader(w)
    invites = []
    handle = leader.handle

    def spy(topic, payload):
        out = handle(topic, payload)
        invites.extend(p for p in out if p.topic.endswith("/to/v1") and unpack(p.payload, "x")[0].get("phase") == 2)
        return out
    leader.handle = spy
    run_prio_session(leader, w["helpers"], w["agents"], list(w["agents"]))
    h, blobs = unpack(invites[0].payload, "invite")
    rh, rb = unpack(blobs[-1], "result")
    forged_set = pack(h, *blobs[:-1], pack(dict(rh, accepted=[1, 2, 3]), *rb))
    own_only = pack(h, *blobs[:-1], pack(rh, rb[0], rb[1], rb[1], rb[1]))      # the leader's signature thrice
    for forged in (forged_set, own_only):
        fresh = PrioAgent(agent.identity, w["trust"], w["params"], SessionLedger(), PREFIX, {7: w["inputs"]["v1"]})
        fresh._u[(7, 0)] = w["params"].wide.clip(w["inputs"]["v1"])[0]
        assert fresh.on_message(invites[0].topic, forged) == []
        assert "signature" in fresh.refusals[-1]


def test_a_helper_refuses_a_roster_with_an_aggregator_as_a_vehicle():
    """The leader's own certificate in the roster is a Sybil whose input it knows: with k = 2 the session's
    mean would give the victim's input away. Found by attacking the fleet mode, where the service holds
    ``aggregator-a``'s identity."""
    w = _world(n=1, min_inputs=2)
    sybil = PrioAgent(w["ka"].identity, w["trust"], w["params"], SessionLedger(), PREFIX, {7: np.zeros(L)},
                      rng=np.random.default_rng(9))
    leader = _leader(w)
    run_prio_session(leader, w["helpers"], {"v1": w["agents"]["v1"], "aggregator-a": sybil}, ["v1", "aggregator-a"])
    assert leader.result is None and leader.state == "aborted"
    for h in w["helpers"]:
        done = h.session((7, 0))
        assert any("aggregator id 'aggregator-a'" in r for k, r in done.events if k == "refused")
        assert h.log.released(session_id(7, 0), 1) is None


def test_no_message_raises_out_of_any_party():
    w = _world()
    leader = _leader(w)
    leader.open(list(w["agents"]))
    rng = np.random.default_rng(3)
    junk = [b"", b"\x00" * 3, rng.bytes(64), pack({"t": "invite", "phase": 1}), pack({"t": "sums", "phase": 1}),
            pack({"blobs": [10]}), b"\xff\xff\xff\x7f" + b"{}"]
    base = leader.topics.base
    for payload in junk:
        assert leader.handle(f"{base}/up/v1", payload) == []
        assert leader.handle(f"{base}/agg/aggregator-b", payload) == []
        for h in w["helpers"]:
            assert h.handle(f"{base}/agg/aggregator-a", payload) == []
            assert h.handle(f"{base}/fwd/{h.keys.party}", payload) == []
        assert w["agents"]["v1"].on_message(f"{base}/to/v1", payload) == []
    assert len(leader.events) == 2 * len(junk)
    # signed by the right party, with every message kind and nonsense fields
    kb = w["keys"]["aggregator-b"]
    topic = f"{base}/agg/aggregator-b"
    for kind in ("commit", "reveal", "vshares", "set", "sums", "result", "close", "open", "closed", "abort", "x"):
        for head, blobs in (({}, []), ({"phase": 1, "ids": "x", "refused": 3, "accepted": [0]}, [b"\x01" * 33]),
                            ({"phase": 1, "ids": [1], "refused": {"1": "x"}, "accepted": [1]}, [b"", b"\x00" * 7])):
            leader.handle(topic, seal(kb.identity, topic, pack(dict(head, t=kind), *blobs)))


def test_parameters_file_round_trip_and_bad_input_lines(tmp_path, capsys):
    import json

    from roadcollab.network.prio_mqtt import main, params_from_dict, params_to_dict
    w = _world()
    back, prefix = params_from_dict(json.loads(json.dumps(params_to_dict(w["params"], PREFIX))), "p.json")
    assert prefix == PREFIX and back.phases == 3 and back.min_inputs == 3 and back.helper_ids == THREE
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


# -- one deviating aggregator --------------------------------------------------------------------------------


def _deviating(base, *, sums=None, vshares=None, set_=None, coin=None):
    """``base`` (PrioLeader or PrioHelper) that changes what it sends: its sums (``sums(k, acc, sums)``), its
    verifier shares (``vshares(k, report)``), its announced set (``set_(k, acc)``) or its revealed coin."""

    class Deviating(base):
        def _send(self, kind, k, header=None, *blobs):
            header = dict(header or {})
            ph = self._phases.get(k)
            if kind == "sums" and sums is not None:
                own = ph.sums[self.party]
                changed = ph.sums[self.party] = sums(k, ph.accepted, {j: v.copy() for j, v in own.items()})
                f = self.params.encoding(k).field
                blobs = (f.to_bytes(np.concatenate([changed[j] for j in self.comps])),)
            if kind == "set" and set_ is not None:
                header["accepted"] = list(set_(k, tuple(header["accepted"])))
            if kind == "reveal" and coin is not None:
                blobs = (coin(k, blobs[0]),)
            if kind == "vshares" and vshares is not None:
                header, blobs = vshares(self, k, header, blobs)
            return super()._send(kind, k, header, *blobs)
    return Deviating


def _steer(enc_of, shift):
    """Add ``shift`` m to every value of the phase-1 mean through this aggregator's first component's sum."""
    def sums(k, acc, own):
        if k == 1:
            enc = enc_of(1)
            delta = np.rint(shift * len(acc) / enc.scale).astype(np.int64)
            j = min(own)
            own[j] = (own[j] + np.array([int(x) for x in delta], dtype=object)) % enc.field.p
        return own
    return sums


def test_a_deviating_leader_cannot_steer_the_centre_the_vehicles_clip_around():
    """Found by attacking the fleet mode with two aggregators: the leader adds an offset to its phase-1 sum
    share, the helper signs the shifted ``m_1`` and every vehicle clips its phase-2 deviation around the
    leader's chosen point (three such queries recovered two honest inputs to l2 error 0.004 where the mean
    alone gives 0.053). With three aggregators the two holders of the shifted component disagree: both helpers
    refuse to sign, the session aborts in phase 1, and no vehicle is invited to clip around anything."""
    w = _world()
    Steering = _deviating(PrioLeader, sums=_steer(w["params"].encoding, 1.0))
    leader = _leader(w, cls=Steering)
    run_prio_session(leader, w["helpers"], w["agents"], list(w["agents"]))
    assert leader.state == "aborted" and leader.result is None and leader.phase == 1
    for h in w["helpers"]:
        events = h.finished[(7, 0)][1].events
        assert any(k == "aborted" and "report different sums" in r for k, r in events), events
    assert not any(key[2] > 1 for a in w["agents"].values() for key in a._answers)


def test_with_two_aggregators_the_steered_centre_goes_unnoticed():
    """The same attack with one helper: nothing can see it (why a fleet's default is three aggregators)."""
    w = _world(helpers=TWO)
    Steering = _deviating(PrioLeader, sums=_steer(w["params"].encoding, 1.0))
    leader = _leader(w, cls=Steering)
    run_prio_session(leader, w["helpers"], w["agents"], list(w["agents"]))
    assert leader.state == "finished"
    assert any(key[2] == 2 for key in w["agents"]["v1"]._answers)          # phase 2 around the steered centre


@pytest.mark.parametrize("who", ["aggregator-b", "aggregator-c"])
def test_a_deviating_helper_cannot_steer_the_centre_either(who):
    w = _world()
    params = w["params"]
    from roadcollab.network.priohelper import PrioHelper
    import roadcollab.network.priohelper as helper_mod
    j = params.helper_ids.index(who)
    svc = w["helpers"][j]
    Bad = _deviating(PrioHelper, sums=_steer(params.encoding, -0.5))
    orig = helper_mod.PrioHelper
    helper_mod.PrioHelper = Bad
    try:
        leader = _leader(w)
        run_prio_session(leader, w["helpers"], w["agents"], list(w["agents"]))
    finally:
        helper_mod.PrioHelper = orig
    assert leader.state == "aborted" and leader.result is None and leader.phase == 1
    assert any("report different sums" in r for k, r in leader.events if k == "aborted"), leader.events
    assert svc.finished[(7, 0)][1].aborted or svc.finished[(7, 0)][1].closed


class _Forging(PrioLeader):
    """A leader that gets vehicle 3 accepted whatever it sent: it waits for the others' verifier shares, then
    reports, for the component(s) it holds, values that make the joint verifier all zeros (which passes)."""

    def _vshares(self, ph):
        others = [p for p in self.params.aggregators if p != self.party]
        if not all(p in ph.reports for p in others):
            return None                                   # the last mover
        return super()._vshares(ph)

    def _send(self, kind, k, header=None, *blobs):
        ph = self._phases.get(k)
        if kind == "vshares" and 3 in ph.agg.shares:
            p = self.params.encoding(k).field.p
            mine = ph.reports[self.party][3]
            hold = {j for j in range(self.count)}
            got = {}
            for party in self.params.aggregators:
                if party != self.party:
                    got.update(ph.reports[party][3].values)
            rest = sum((got[j] for j in hold - set(self.comps)), np.zeros_like(mine.values[0]))
            first, *others = self.comps
            mine.values[first][:] = (-(rest + sum((mine.values[j] for j in others), 0 * rest))) % p
            checked = [i for i in ph.closed if not isinstance(ph.reports[self.party][i], str)]
            values = [x for i in checked for j in self.comps for x in ph.reports[self.party][i].values[j]]
            blobs = (blobs[0], self.params.encoding(k).field.to_bytes(np.array(values, dtype=object)))
        return super()._send(kind, k, header, *blobs)


@pytest.mark.parametrize("helpers", [TWO, THREE])
def test_a_deviating_aggregator_cannot_get_a_cheating_vehicle_accepted(monkeypatch, helpers):
    """With two aggregators the leader's forged verifier share gets the cheater accepted (soundness needs both
    to follow the protocol); with three, the other holder of the forged component reports the true share and
    the session aborts before any sum is released."""
    w = _world(helpers=helpers)
    _cheat(monkeypatch, "v3", 1)
    leader = _leader(w, cls=_Forging)
    run_prio_session(leader, w["helpers"], w["agents"], list(w["agents"]))
    if helpers == TWO:
        assert leader.state == "finished" and 3 in leader.accepted        # the attack works with two
        return
    assert leader.state == "aborted" and leader.result is None
    for h in w["helpers"]:
        events = h.finished[(7, 0)][1].events
        assert any(k == "aborted" and "report different verifier shares" in r for k, r in events), events
        assert h.log.released(session_id(7, 0), 1) is None


def test_a_deviating_leader_cannot_show_the_helpers_different_sets_or_open_another_coin():
    w = _world()
    # announces a set without vehicle 2 (a sum over it and the previous one would give vehicle 2 away)
    leader = _leader(w, cls=_deviating(PrioLeader, set_=lambda k, acc: tuple(i for i in acc if i != 2)))
    run_prio_session(leader, w["helpers"], w["agents"], list(w["agents"]))
    assert leader.state == "aborted"
    for h in w["helpers"]:
        done = h.finished[(7, 0)][1]
        assert any(k == "aborted" and "announced another accepted set" in r for k, r in done.events), done.events
        assert h.log.released(session_id(7, 0), 1) is None                     # nothing released at all
    w = _world()
    leader = _leader(w, cls=_deviating(PrioLeader, coin=lambda k, c: bytes(32)))
    run_prio_session(leader, w["helpers"], w["agents"], list(w["agents"]))
    assert leader.state == "aborted"
    for h in w["helpers"]:
        done = h.finished[(7, 0)][1]
        assert any("coin does not open its commitment" in r for k, r in done.events if k == "aborted"), done.events


def test_the_query_randomness_needs_every_coin():
    """No aggregator alone knows ``r`` before the uploads close: the key hashes every revealed coin, so one
    aggregator's coin (known to a colluding vehicle in advance) leaves it uniform."""
    from roadcollab.privacy.secagg_replicated import coin_commitment, coin_key
    from roadcollab.privacy.secagg_validity import query_randomness

    enc = ValidityEncoding(np.full(L, 4.0), 2.0 ** -12)
    coins = [bytes([1]) * 32, bytes([2]) * 32, bytes([3]) * 32]
    r0 = query_randomness(enc, coin_key(b"s", coins), b"s", 1, b"j")[0]
    for j in range(3):
        other = list(coins)
        other[j] = bytes([9]) * 32
        assert query_randomness(enc, coin_key(b"s", other), b"s", 1, b"j")[0] != r0
    assert coin_commitment(b"s", "a", coins[0]) != coin_commitment(b"s", "b", coins[0])


# -- a long-running helper -------------------------------------------------------------------------------------


def _opened(w, helper, epoch):
    """Feed the helper a new leader's ``open`` for session (7, epoch)."""
    leader = _leader(w, epoch=epoch)
    m = leader.open(list(w["agents"]))[0]
    assert m.topic.endswith("/agg/aggregator-a")
    return helper.handle(m.topic, m.payload)


def test_a_finished_session_leaves_the_helper_its_state_dropped_and_a_replay_gets_nothing():
    # A long-running helper kept every session's per-vehicle state for ever (noticed in issue 20's review).
    w = _world()
    leader, helper = _leader(w), w["helpers"][0]
    seen, handle = [], helper.handle
    helper.handle = lambda t, p: seen.append((t, p)) or handle(t, p)
    run_prio_session(leader, w["helpers"], w["agents"], list(w["agents"]))
    assert leader.state == "finished" and helper.sessions == {}
    why, done = helper.finished[(7, 0)]
    assert why == "finished" and done.finished and not done._phases and not done.roster
    assert [e for e in done.events if e[0] == "released"][-1] == ("released", "phase 3 over 5 vehicles")
    assert seen and not [out for t, p in seen for out in handle(t, p)]
    assert helper.sessions == {}


def test_the_helper_refuses_sessions_beyond_its_open_limit_and_ends_idle_ones():
    w = _world()
    now = [0.0]
    helper = PrioHelperService(PREFIX, w["params"], w["trust"], w["keys"]["aggregator-b"], ReleaseLog(),
                               max_open=2, max_idle_s=60.0, clock=lambda: now[0])
    for epoch in range(3):
        _opened(w, helper, epoch)
    assert sorted(helper.sessions) == [(7, 0), (7, 1)]
    assert helper.refused == ["session 7/2 refused: 2 sessions are open"]
    now[0] = 50.0
    topic = f"{PREFIX}/prio/7/0/agg/aggregator-a"
    bad = seal(w["ka"].identity, topic, pack({"t": "bogus"}))
    assert helper.handle(topic, bad) == []     # refused: keeps the session no longer alive
    now[0] = 61.0
    assert sorted(helper.expire()) == [(7, 0), (7, 1)]
    assert helper.sessions == {} and helper.finished[(7, 0)][0] == "idle"
    assert helper.finished[(7, 0)][1].roster == {}
    assert _opened(w, helper, 0) == [] and (7, 0) not in helper.sessions      # an ended session stays ended
    _opened(w, helper, 2)
    assert list(helper.sessions) == [(7, 2)]                                   # room again for a new one


def test_only_an_aggregators_signed_message_on_its_own_topic_creates_a_helper_session():
    w = _world()
    helper = w["helpers"][0]
    assert PrioHelperService.__init__.__kwdefaults__["max_open"] is None     # a dropped session spends measurements
    leader = _leader(w, epoch=0)
    opening = next(m for m in leader.open(list(w["agents"])) if m.topic.endswith("/agg/aggregator-a"))
    vehicle = w["agents"]["v1"].identity
    forged = seal(vehicle, opening.topic, pack({"t": "open", "phase": 1, "roster": {"v1": 1}}))
    helper.handle(opening.topic, forged)                                        # signed, but by a vehicle
    c_topic = opening.topic.replace("aggregator-a", "aggregator-c")
    helper.handle(c_topic, seal(w["keys"]["aggregator-c"].identity, opening.topic, pack({"t": "commit"})))
    helper.handle(opening.topic.replace("/prio/7/", "/prio/07/"), opening.payload)   # another topic, same key
    helper.handle(opening.topic, b"not a signed message")
    helper.handle(f"{PREFIX}/prio/7/0/fwd/aggregator-c", opening.payload)      # another helper's forwards
    assert helper.sessions == {}
    helper.handle(opening.topic, opening.payload)
    assert list(helper.sessions) == [(7, 0)] and helper.sessions[(7, 0)].roster
