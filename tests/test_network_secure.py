"""Secure aggregation inside the networked engine, over the in-memory transport (issues 19 and 20).

Oracles: the clear in-memory run of the same drives (itself bit-equal to ``estimate_fleet``,
tests/test_network_engine.py); the plain mean of the surviving vehicles' inversions after a dropout;
the rules of :mod:`roadcollab.network.rounds` (one measurement of a segment to one round; refusals with
a reason); a service rebuilt from its store mid-round finishes the round with the same sum.
"""

import json
import os
import stat

import numpy as np
import pytest

from roadcollab import MessageError, ParameterError
from roadcollab.cli.main import main
from roadcollab.network.agent import VehicleAgent
from roadcollab.network.aggregation import AggregationPolicy, segment_input, sums_from_total
from roadcollab.network.engine import VehicleEngine
from roadcollab.network.fleetdir import load_aggregation
from roadcollab.network.memory import _pump_all, run_in_memory
from roadcollab.network.messages import Topics, encode_contribution, seal
from roadcollab.network.relaykey import RelayKey
from roadcollab.network.results import results_from_store
from roadcollab.network.rounds import SecureRounds
from roadcollab.network.secround_agent import RoundAgent
from roadcollab.network.service import Service
from roadcollab.network.store import ServiceStore
from roadcollab.network.transport import MemoryBroker
from roadcollab.privacy.secagg_store import SessionLedger
from roadcollab.wire.identity import FleetAuthority, VehicleIdentity

POLICY = AggregationPolicy(mode="secure", round_size=4, min_inputs=3, threshold=3)


@pytest.fixture(scope="module")
def drives(mixed_drives):
    return list(mixed_drives)   # tests/conftest.py: built once per session


@pytest.fixture(scope="module")
def plan(mixed_plan):
    return mixed_plan


@pytest.fixture(scope="module")
def clear(mixed_clear_run):
    return results_from_store(mixed_clear_run[0])


def _rel(a, b):
    return float(np.nanmax(np.abs(a - b)) / np.nanmax(np.abs(b)))


def test_secure_run_equals_the_clear_run_and_the_service_reads_no_inversion(drives, plan, clear):
    store, broker = run_in_memory(drives, plan, aggregation=POLICY)
    sec = results_from_store(store)
    assert np.array_equal(sec.position, clear.position) and np.array_equal(sec.coverage, clear.coverage)
    assert np.array_equal(np.isnan(sec.fused), np.isnan(clear.fused))
    assert _rel(sec.fused, clear.fused) <= 1e-9                 # 2^-40 m fixed point: about 1e-11 here
    assert _rel(sec.fused, clear.fused) > 0                     # it did go through the fixed-point ring
    rounds = store.rounds()
    assert len(rounds) == len(store.fused()) and all(r["phase"] == "finished" and len(r["used"]) == 4 for r in rounds)
    assert all(d.startswith(b"RCSEAL1\x00") for _, _, d, _ in store.contributions())
    for k in ("single", "inversion", "collaborative"):           # the service holds no vehicle's estimate
        assert np.isnan(sec.elevation[k]).all()
    inv = clear.elevation["inversion"]
    for _, _, d, _ in store.contributions():                     # nor any of their bytes in the clear
        assert np.ascontiguousarray(inv[0][~np.isnan(inv[0][:, 0])][:4], "<f8").tobytes() not in d


def _secure_world(drives, plan, store, *, agent_cls=RoundAgent, dead=()):
    auth = FleetAuthority.generate(plan.fleet_id)
    trust, relay = auth.trust(), RelayKey.generate()
    broker = MemoryBroker()
    agents, cars = {}, {}
    for j, d in enumerate(drives):
        ident = VehicleIdentity.enroll(auth, f"v{j + 1}")
        cls = agent_cls if ident.vehicle_id in dead else RoundAgent
        r = cls(ident, trust, POLICY.spec, SessionLedger(), f"rc/{plan.fleet_id}", {})
        agents[ident.vehicle_id] = VehicleAgent(VehicleEngine(d, plan, index=j), ident, trust, rounds=r,
                                                relay_key=relay)
        cars[ident.vehicle_id] = broker.client()
        for f in agents[ident.vehicle_id].subscriptions:
            cars[ident.vehicle_id].subscribe(f)
    return auth, trust, broker, agents, cars


def _service(store, trust):
    rounds = SecureRounds(store, trust, POLICY, f"rc/{store.plan.fleet_id}", phase_timeout_s=0.0,
                          round_wait_s=float("inf"))
    return Service(store, trust, rounds=rounds)


def _drive_all(service, svc, agents, cars):
    for vid, a in agents.items():
        for p in a.start():
            cars[vid].publish(p.topic, p.payload, p.retain)
        _pump_all(service, svc, cars, agents, set(), limit=1000)


class DiesAfterShares(RoundAgent):
    """Deals its shares, then answers nothing (a process killed between rounds 1 and 2)."""

    def on_message(self, topic, payload):
        if any(f'"type":"{k}"'.encode() in bytes(payload[:40]) for k in ("dealt", "survivors", "signatures")):
            return []
        return super().on_message(topic, payload)


@pytest.mark.slow  # 7 s: a secure round end to end
def test_a_vehicle_gone_after_its_shares_is_left_behind(drives, plan):
    store = ServiceStore(":memory:", plan)
    auth, trust, broker, agents, cars = _secure_world(drives, plan, store, agent_cls=DiesAfterShares, dead={"v4"})
    service = _service(store, trust)
    svc = broker.client()
    for f in service.subscriptions:
        svc.subscribe(f)
    _drive_all(service, svc, agents, cars)
    for _ in range(10):                                          # the service's timeouts
        for p in service.tick():
            svc.publish(p.topic, p.payload)
        _pump_all(service, svc, cars, agents, set(), limit=1000)
        if not service.rounds.active:
            break
    rounds = store.rounds()
    assert rounds and all(r["phase"] == "finished" and r["used"] == ["v1", "v2", "v3"] for r in rounds), rounds
    assert all(r["reason"].endswith("dropped [4]") for r in rounds)
    assert all(agents[v].done for v in ("v1", "v2", "v3")) and not agents["v4"].done
    ref = results_from_store(run_in_memory(drives[:3], plan)[0])   # the mean of v1-v3's inversions
    sec = results_from_store(store)
    lo = int(round((sec.position[0] - ref.position[0]) / plan.spacing))
    part = ref.fused[lo:lo + len(sec.position)]
    assert _rel(sec.fused, part) <= 1e-9
    assert np.array_equal(sec.coverage, ref.coverage[lo:lo + len(sec.position)])


def test_a_service_restarted_mid_round_finishes_it_from_its_journal(drives, plan, clear, tmp_path):
    store = ServiceStore(tmp_path / "s.sqlite", plan)
    auth, trust, broker, agents, cars = _secure_world(drives, plan, store)
    service = _service(store, trust)
    svc = broker.client()
    for f in service.subscriptions:
        svc.subscribe(f)
    for vid, a in agents.items():
        for p in a.start():
            cars[vid].publish(p.topic, p.payload, p.retain)
        _pump_all(service, svc, cars, agents, set(), limit=1000)
        if vid == "v3":
            break
    # v4 contributes; the rounds open; its messages and the others' answers are delivered up to the masked
    # inputs, then the service is killed (its memory gone): only the store remains.
    for p in agents["v4"].start():
        cars["v4"].publish(p.topic, p.payload, p.retain)
    for _ in range(40):
        _pump_one_step(service, svc, cars, agents)
        if any(r["phase"] == "consistency" for r in store.rounds()):
            break
    phases = {(r["segment"], r["epoch"]): r["phase"] for r in store.rounds()}
    assert any(p not in ("finished", "aborted") for p in phases.values()), phases
    store.close()
    store2 = ServiceStore(tmp_path / "s.sqlite", plan)
    service2 = _service(store2, trust)
    assert set(service2.rounds.active) == {k for k, p in phases.items() if p not in ("finished", "aborted")}
    for k, co in service2.rounds.active.items():                 # replayed to the phase the store recorded
        assert co.phase == phases[k]
    svc2 = broker.client()
    for f in service2.subscriptions:
        svc2.subscribe(f)
    for p in service2.on_connect():                              # the current phase's messages again
        svc2.publish(p.topic, p.payload, p.retain)
    for _ in range(10):
        _pump_all(service2, svc2, cars, agents, set(), limit=1000)
        if not service2.rounds.active:
            break
        for p in service2.tick():
            svc2.publish(p.topic, p.payload)
    assert all(r["phase"] == "finished" and len(r["used"]) == 4 for r in store2.rounds())
    assert all(a.done for a in agents.values())
    assert _rel(results_from_store(store2).fused, clear.fused) <= 1e-9


def _pump_one_step(service, svc, cars, agents):
    """One message each way at most (to stop a run mid-round)."""
    m = svc.receive(0.0)
    if m is not None:
        for p in service.handle(*m):
            svc.publish(p.topic, p.payload, p.retain)
    for vid, car in cars.items():
        m = car.receive(0.0)
        if m is not None:
            for p in agents[vid].on_message(*m):
                car.publish(p.topic, p.payload, p.retain)


def test_refusals_of_a_secure_service(drives, plan):
    store, _ = run_in_memory(drives, plan, aggregation=POLICY)
    auth = FleetAuthority.generate(plan.fleet_id)
    trust = auth.trust()
    service = _service(store, trust)
    ident = VehicleIdentity.enroll(auth, "v9")
    topics = Topics(plan.fleet_id)
    hello_t = topics.hello("v9")
    service.handle(hello_t, seal(ident, hello_t, json.dumps({"segments": [0]}).encode()))
    c = VehicleEngine(drives[0], plan).contributions()[0]
    t = topics.segment("v9", c.segment)
    assert service.handle(t, seal(ident, t, encode_contribution(c))) == []   # a clear one: refused
    assert any("RCSEAL1" in why for _, _, _, why in store.events("refused"))
    late = f"rc/{plan.fleet_id}/secagg/0/0/masked/v1"
    assert service.handle(late, b"whatever") == []
    assert any("round 0/0 is finished" in why for _, _, _, why in store.events("refused"))
    assert service.handle(f"rc/{plan.fleet_id}/secagg/0/7/advert/v1", b"x") == []
    assert any("no round 0/7 was opened" in why for _, _, _, why in store.events("refused"))


def test_a_vehicle_gives_one_measurement_of_a_segment_to_one_round(plan, tmp_path):
    auth = FleetAuthority.generate("t")
    trust = auth.trust()
    ident = VehicleIdentity.enroll(auth, "v1")
    z = np.zeros((2 * plan.points_per_segment, 2))
    ledger = SessionLedger(tmp_path / "ledger.sqlite")
    a = RoundAgent(ident, trust, POLICY.spec, ledger, "rc/t", {0: z})
    invite = json.dumps({"type": "invite", "id": 1, "segment": 0, "epoch": 0}).encode()
    assert a.on_message("rc/t/secagg/0/0/to/v1", invite)               # epoch 0: advertises
    assert a.on_message("rc/t/secagg/0/0/to/v1", invite) == a.on_message("rc/t/secagg/0/0/to/v1", invite)
    ledger.record_contribution(a.rounds[(0, 0)].session, [1, 2, 3])    # as mask_input records it
    again = json.dumps({"type": "invite", "id": 1, "segment": 0, "epoch": 1}).encode()
    assert a.on_message("rc/t/secagg/0/1/to/v1", again) == []
    assert "went to round (0, 0)" in a.refusals[-1]
    b = RoundAgent(ident, trust, POLICY.spec, SessionLedger(tmp_path / "ledger.sqlite"), "rc/t", {0: z})  # restarted
    assert b.on_message("rc/t/secagg/0/1/to/v1", again) == [] and "went to epoch 0" in b.refusals[-1]
    assert b.finished(0)                                               # its input of segment 0 is spent


def test_round_inputs_carry_the_sums_of_the_clear_fusion(drives, plan):
    cs = VehicleEngine(drives[1], plan).contributions()
    c = cs[-1]                                                         # a partly covered segment
    z = segment_input(plan, c)
    total, count = sums_from_total(plan, z + z)
    m = plan.points_per_segment
    a = c.i0 - plan.segment_range(c.segment)[0]
    assert np.array_equal(total[a:a + c.n], 2 * c.inversion) and count.sum() == 2 * c.n
    assert not total[:a].any() and set(np.unique(count)) <= {0, 2}
    bad = z.copy()
    bad[m] = 0.5
    with pytest.raises(ParameterError, match="whole counts"):
        sums_from_total(plan, bad)


def test_policy_and_enroll(tmp_path, capsys):
    with pytest.raises(ParameterError, match="round_size"):
        AggregationPolicy(mode="secure", round_size=9, min_inputs=3, threshold=3)      # > 2t - c - 1 = 5
    with pytest.raises(ParameterError, match="mode"):
        AggregationPolicy(mode="fuzzy")
    with pytest.raises(ParameterError, match="unknown aggregation keys"):
        AggregationPolicy.from_dict({"mode": "secure", "k": 3}, "fleet.toml")
    assert main(["enroll", "--fleet", str(tmp_path / "f"), "--vehicles", "4", "--aggregation", "secure",
                 "--min-inputs", "3", "--threshold", "3", "--round-size", "4"]) == 0
    assert "secure aggregation, rounds of 4" in capsys.readouterr().out
    assert load_aggregation(tmp_path / "f") == POLICY
    keys = {(tmp_path / f"f/vehicles/v{k}/relay.key").read_bytes() for k in range(1, 5)}
    assert len(keys) == 1 and len(next(iter(keys))) == 32
    assert stat.S_IMODE(os.stat(tmp_path / "f/vehicles/v1/relay.key").st_mode) == 0o600
    assert not list((tmp_path / "f" / "service").glob("relay*"))          # the service gets no relay key
    assert main(["enroll", "--fleet", str(tmp_path / "g"), "--vehicles", "4", "--aggregation", "secure",
                 "--min-inputs", "3", "--round-size", "8"]) == 2
    assert "--round-size" in capsys.readouterr().err
    assert main(["enroll", "--fleet", str(tmp_path / "h"), "--vehicles", "2"]) == 0
    assert not load_aggregation(tmp_path / "h").secure and not (tmp_path / "h/vehicles/v1/relay.key").exists()


def test_relay_key_binds_the_topic():
    k = RelayKey.generate()
    blob = k.seal("rc/t/v/v1/seg/3", b"inversion")
    assert k.open("rc/t/v/v1/seg/3", blob) == b"inversion"
    with pytest.raises(MessageError, match="does not open"):
        k.open("rc/t/v/v2/seg/3", blob)
    with pytest.raises(MessageError, match="does not open"):
        RelayKey.generate().open("rc/t/v/v1/seg/3", blob)
    with pytest.raises(MessageError, match="does not open"):
        k.open("rc/t/v/v1/seg/3", blob[:-1] + bytes([blob[-1] ^ 1]))


class _Clock:
    """A wall clock the test moves (both services read it)."""

    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


def test_two_services_on_one_store_hold_each_round_once_and_take_over_a_dead_ones(drives, plan, clear, tmp_path):
    """``serve --shared`` in secure mode: services A and B on one SQLite file, both receiving every round
    message. A claims the rounds (one open round per segment, whoever opens it); B answers none of them.
    A stops mid-round (killed: no more ticks); once its lease has run out B adopts the rounds from the
    journal and finishes them with the clear run's sums. A's late writes are fenced (nothing twice)."""
    clock = _Clock()
    store_a, store_b = ServiceStore(tmp_path / "s.sqlite", plan), ServiceStore(tmp_path / "s.sqlite", plan)
    auth, trust, broker, agents, cars = _secure_world(drives, plan, store_a)

    def service(store, owner):
        r = SecureRounds(store, trust, POLICY, f"rc/{plan.fleet_id}", phase_timeout_s=5.0,
                         round_wait_s=float("inf"), clock=clock, owner=owner, lease_s=10.0)
        svc = Service(store, trust, rounds=r)
        client = broker.client()
        for f in svc.subscriptions:
            client.subscribe(f)
        return svc, client

    (a, ca), (b, cb) = service(store_a, "A"), service(store_b, "B")
    for vid, ag in agents.items():            # A applies every contribution and opens every round
        for p in ag.start():
            cars[vid].publish(p.topic, p.payload, p.retain)
    for _ in range(60):
        _pump_one_step(a, ca, cars, agents)
        m = cb.receive(0.0)                   # B sees the round messages too, and says nothing
        if m is not None and "/secagg/" in m[0]:
            assert b.handle(*m) == []
        if any(r["phase"] == "consistency" for r in store_a.rounds()):
            break
    held = set(a.rounds.active)
    assert held and not b.rounds.active
    assert b.rounds.maybe_open(next(iter(held))[0]) == []          # the segment's round is A's
    clock.t += 5.0                                                 # A's lease still runs: B adopts nothing
    assert b.tick() == [] and not b.rounds.active
    clock.t += 6.0                                                 # A is dead: its lease ran out
    for p in b.tick():
        cb.publish(p.topic, p.payload, p.retain)
    assert set(b.rounds.active) == held
    for _ in range(20):
        _pump_all(b, cb, cars, agents, set(), limit=1000)
        if not b.rounds.active:
            break
        for p in b.tick():
            cb.publish(p.topic, p.payload)
    assert all(r["phase"] == "finished" and len(r["used"]) == 4 for r in store_b.rounds())
    assert all(ag.done for ag in agents.values())
    assert _rel(results_from_store(store_b).fused, clear.fused) <= 1e-9
    key, co = next(iter(a.rounds.active.items()))                  # A wakes up: its round is gone
    co.journal.append(("advance",))
    assert a.rounds._step(key, co, []) == [] and key not in a.rounds.active
    assert _rel(results_from_store(store_b).fused, clear.fused) <= 1e-9
    store_a.close(), store_b.close()
