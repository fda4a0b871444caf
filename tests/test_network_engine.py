"""The per-segment engine and the service's protocol over the in-memory transport (issue 19, part 1).

Oracle: :func:`roadcollab.experiments.drives.fleet_estimation.estimate_fleet` (what ``roadcollab estimate`` runs for
drives at different speeds). The engine cuts the same computation by segment, so its results must be the
same numbers exactly (bit for bit: the same operations on the same values).
"""

import numpy as np
import pytest

from roadcollab import MessageError, ParameterError
from roadcollab.experiments.drives.fleet_estimation import estimate_fleet
from roadcollab.network.agent import VehicleAgent
from roadcollab.network.engine import VehicleEngine
from roadcollab.network.messages import Topics, decode_contribution, encode_contribution, seal
from roadcollab.network.plan import RoadPlan
from roadcollab.network.results import results_from_store
from roadcollab.network.service import Service
from roadcollab.network.store import ServiceStore
from roadcollab.network.transport import topic_matches
from roadcollab.wire.identity import FleetAuthority, VehicleIdentity


@pytest.fixture(scope="module")
def drives(mixed_drives):
    return list(mixed_drives)   # tests/conftest.py: built once per session


@pytest.fixture(scope="module")
def plan(mixed_plan):
    return mixed_plan


def test_in_memory_run_equals_estimate_fleet(drives, mixed_clear_run):
    est = estimate_fleet(drives)
    store, broker = mixed_clear_run
    r = results_from_store(store)
    assert np.array_equal(r.position, est.position)
    for k in ("single", "inversion", "collaborative", "fused"):
        assert np.array_equal(r.elevation[k], est.elevation[k], equal_nan=True), k
    assert np.array_equal(r.fused, est.fused, equal_nan=True)
    assert np.array_equal(r.coverage, est.coverage)
    assert store.status()["refused"] == {}
    assert broker.bytes_published > 0


def test_estimate_fleet_in_memory_is_estimate_fleet(drives):
    from roadcollab.network.memory import estimate_fleet_in_memory

    est, mem = estimate_fleet(drives[:2]), estimate_fleet_in_memory(drives[:2])
    assert np.array_equal(mem.position, est.position) and mem.band_low_per_m == est.band_low_per_m
    for k in est.elevation:
        assert np.array_equal(mem.elevation[k], est.elevation[k], equal_nan=True), k


def test_plan_band_edge_is_estimates():
    assert RoadPlan(min_speed=12.0).band_low_per_m == 0.5 / 12.0
    with pytest.raises(ParameterError, match="segment_length must be a whole number"):
        RoadPlan(segment_length=0.5)
    with pytest.raises(ParameterError, match="x.toml: unknown plan keys"):
        RoadPlan.from_dict({"spacing": 0.05, "bogus": 1}, "x.toml")


def test_topic_filters():
    assert topic_matches("rc/f/v/+/#", "rc/f/v/v1/seg/3")
    assert not topic_matches("rc/f/v/+/hello", "rc/f/v/v1/seg/3")
    assert topic_matches("rc/f/seg/+/waiting", "rc/f/seg/12/waiting")
    assert not topic_matches("rc/f/seg/+/waiting", "rc/f/seg/12")


@pytest.fixture(scope="module")
def fleet_keys():
    auth = FleetAuthority.generate("t")
    return auth, {v: VehicleIdentity.enroll(auth, v) for v in ("v1", "v2")}


def _service(plan, auth):
    return Service(ServiceStore(":memory:", plan), auth.trust())


def _contrib(drives, plan):
    return VehicleEngine(drives[0], plan).contributions()[1]


def test_contribution_round_trip_and_limits(drives, plan):
    c = _contrib(drives, plan)
    back = decode_contribution(encode_contribution(c), plan, c.segment)
    assert back.i0 == c.i0 and np.array_equal(back.inversion, c.inversion)
    data = encode_contribution(c)
    with pytest.raises(MessageError, match="on the topic of segment"):
        decode_contribution(data, plan, c.segment + 1)
    with pytest.raises(MessageError, match="bytes of values"):
        decode_contribution(data[:-8], plan, c.segment)
    bad = bytearray(data)
    bad[-8:] = np.array([np.nan]).tobytes()
    with pytest.raises(MessageError, match="finite"):
        decode_contribution(bytes(bad), plan, c.segment)


def test_service_refuses_forgeries_and_applies_copies_once(drives, plan, fleet_keys):
    auth, ids = fleet_keys
    svc = _service(plan, auth)
    T = Topics("t")
    agent = VehicleAgent(VehicleEngine(drives[0], plan), ids["v1"], auth.trust())
    hello = agent.start()[0]
    assert svc.handle(hello.topic, hello.payload)               # the hello ack
    c = _contrib(drives, plan)
    topic = T.segment("v1", c.segment)
    good = seal(ids["v1"], topic, encode_contribution(c))
    # v2 signs a message and publishes it on v1's topic: the certificate is not the topic's vehicle.
    assert svc.handle(topic, seal(ids["v2"], topic, encode_contribution(c))) == []
    # v1's own envelope replayed on another segment's topic: the signature binds the topic.
    assert svc.handle(T.segment("v1", c.segment + 1), good) == []
    # Random bytes on every topic.
    rng = np.random.default_rng(0)
    for t in (topic, hello.topic, T.segment("v2", 0), "rc/t/v/v1/other", "rc/t/x"):
        assert svc.handle(t, rng.bytes(300)) == []
    assert svc.store.status()["contributions"] == 0
    first = svc.handle(topic, good)
    assert [p.retain for p in first] == [False, True]
    again = svc.handle(topic, good)                             # a QoS 1 redelivery
    assert len(again) == 1 and b'"duplicate"' in again[0].payload
    st = svc.store.status()
    assert st["contributions"] == 1 and st["duplicates"] == 1
    reasons = [r for _, _, _, r in svc.store.events("refused")]
    assert any("signed by v2, not by v1" in r for r in reasons)
    assert len(reasons) == 7


def test_contribution_before_hello_is_refused(drives, plan, fleet_keys):
    auth, ids = fleet_keys
    svc = _service(plan, auth)
    c = _contrib(drives, plan)
    topic = Topics("t").segment("v2", c.segment)
    assert svc.handle(topic, seal(ids["v2"], topic, encode_contribution(c))) == []
    assert "before its hello" in svc.store.events("refused")[0][3]
