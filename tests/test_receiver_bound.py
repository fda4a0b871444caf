"""A receiver that a plausible lie cannot steer (issue 20, section 4).

Each attack was first run against the guard before issue 20 (``bounded=False``, stateless): the
coherent exaggeration cost vehicle 2 up to 2.84 x its observer-only MSE and the fake pothole at 0.9 x
the threshold showed in its estimate (5 fake detections in 4 runs). The tests assert the target
(<= 2 x the observer-only MSE, no planted anomaly) for the default guard and that the old guard misses it.
"""

import dataclasses

import numpy as np
import pytest

import roadcollab as rc
from roadcollab.collaboration.guard import ReceiverGuard, fleet_guards
from roadcollab.collaboration.relay import Relay
from roadcollab.errors import ParameterError
from roadcollab.experiments.pipeline import PipelineCache, record_run
from roadcollab.experiments.security.receiver_attacks import receiver_attack_rows
from roadcollab.experiments.seeds import SeedPlan, run_stream

CFG = rc.ExperimentConfig()          # the default fleet (10 vehicles), as the study


@pytest.fixture(scope="module")
def pipe():
    return PipelineCache().pipeline(CFG, 0)


@pytest.fixture(scope="module")
def rows(pipe):
    new = receiver_attack_rows(CFG, n_runs=2, mechanisms=("hardened",), drift_segments=6, pipe=pipe)
    old = receiver_attack_rows(CFG, n_runs=2, mechanisms=("hardened",), drift_segments=6, pipe=pipe,
                               guard_options={"bounded": False}, confirm=False)
    return {r.strategy: r for r in new}, {r.strategy: r for r in old}


@pytest.mark.parametrize("attack", ["coherent_up", "coherent_down", "fake_pothole_09", "slow_drift"])
def test_guard_aware_coherent_lies_cost_at_most_2x_and_plant_nothing(rows, attack):
    r = rows[0][attack]
    assert r.max_ratio_to_observer <= 2.0, r
    assert r.fake_anomalies_reported == 0 and r.real_anomalies_lost == 0, r


def test_the_stateless_accept_or_refuse_guard_is_steered(rows):
    """The same constructions against the guard before issue 20, every detection reported (so that the tests
    above can fail)."""
    old = rows[1]
    assert old["coherent_up"].max_ratio_to_observer > 2.0
    assert old["fake_pothole_09"].fake_anomalies_reported > 0
    assert old["slow_drift"].refused == 0


def test_slow_drift_is_refused_by_the_per_sender_record(rows):
    drift = rows[0]["slow_drift"]
    assert drift.refused >= drift.runs - 3      # judged from the third segment on


def test_honest_senders_keep_their_trust_across_segments(pipe):
    """Honest messages over six segments from every predecessor: the record never refuses one."""
    guards = fleet_guards(pipe.estimators, pipe.road_moment, CFG.sensor_noise_std)
    for ss in SeedPlan(0).runs(6):
        _, _, Ys = record_run(pipe, run_stream(ss, "road"), run_stream(ss, "noise"), CFG.sensor_noise_std)
        for j in range(1, CFG.n_vehicles):
            prev = pipe.estimators[j - 1]
            msg = prev.hardened_message(prev.estimate(None, Y=Ys[j - 1]))
            _, rep = guards[j].feedforward(msg, Ys[j], sender=j - 1)
            assert not rep.whole_message_refused, rep.reasons
    assert max(guards[j].sender_record(j - 1)[0] for j in range(1, CFG.n_vehicles)) < guards[1].drift_limit


def test_a_message_is_guarded_by_default_and_unguarded_only_by_name(pipe):
    """Issue 20: estimate(y, message) applied z x 1e6 unguarded (2.6e10 x). Now it needs a guard or the opt-out."""
    e1, e2 = pipe.estimators[0], pipe.estimators[1]
    ss = SeedPlan(0).runs(1)[0]
    road, ys, Ys = record_run(pipe, run_stream(ss, "road"), run_stream(ss, "noise"), CFG.sensor_noise_std)
    msg = e1.hardened_message(e1.estimate(None, Y=Ys[0]))
    huge = dataclasses.replace(msg, z=1e6 * msg.z)
    assert e2.guard is None
    with pytest.raises(ParameterError, match="no receiver guard.*unguarded=True"):
        e2.estimate(None, huge, Y=Ys[1])
    with pytest.raises(ParameterError, match="no receiver guard"):
        Relay(pipe.estimators[:2], "hardened").run(ys[:2], spectra=Ys[:2])
    truth = pipe.grid.band_limited(pipe.grid.rfft(road.velocity), pipe.grid.n_samples)

    def mse(r):
        return float(np.mean((pipe.grid.band_limited(r.W_hat, pipe.grid.n_samples) - truth) ** 2))
    obs = float(np.mean((pipe.grid.band_limited(e2.estimate(None, Y=Ys[1]).W_obs, pipe.grid.n_samples) - truth) ** 2))
    assert mse(e2.estimate(None, huge, Y=Ys[1], unguarded=True)) > 1e6 * obs        # the paper's algorithm
    guard = ReceiverGuard(e2, pipe.road_moment, CFG.sensor_noise_std).attach()
    try:
        assert e2.guard is guard
        assert mse(e2.estimate(None, huge, Y=Ys[1])) <= 2.0 * obs
        steps = Relay(pipe.estimators[:2], "hardened").run(ys[:2], spectra=Ys[:2])   # uses the attached guard
        assert steps[1].guard is not None and not steps[1].guard.refused
        with pytest.raises(ParameterError, match="exclude each other"):
            Relay(pipe.estimators[:2], "hardened", guard=[None, guard], unguarded=True)
    finally:
        e2.guard = None            # the pipeline is shared through the cache


def test_honest_cost_of_the_bounded_combination(pipe):
    """With an honest message the bounded combination is no worse than Algorithm 1 (measured: 1.17 x
    against 1.45 x the observer-only MSE at vehicle 2, 2 runs) and the gains lie in [0, 1]."""
    guard = ReceiverGuard(pipe.estimators[1], pipe.road_moment, CFG.sensor_noise_std)
    assert np.all((guard.gains >= 0) & (guard.gains <= 1))
    e1, e2 = pipe.estimators[0], pipe.estimators[1]
    for ss in SeedPlan(0).runs(2):
        road, _, Ys = record_run(pipe, run_stream(ss, "road"), run_stream(ss, "noise"), CFG.sensor_noise_std)
        truth = pipe.grid.band_limited(pipe.grid.rfft(road.velocity), pipe.grid.n_samples)[CFG.scored]
        msg = e1.hardened_message(e1.estimate(None, Y=Ys[0]))

        def mse(W, truth=truth):
            return float(np.mean((pipe.grid.band_limited(W, pipe.grid.n_samples)[CFG.scored] - truth) ** 2))
        Wf, _ = guard.feedforward(msg, Ys[1])
        assert mse(e2.estimate(None, Wf=Wf, Y=Ys[1]).W_hat) <= mse(e2.estimate(None, msg, Y=Ys[1], unguarded=True).W_hat)


def test_confirmed_by_own_keeps_only_what_the_receivers_own_data_shows():
    from roadcollab.detection.corroboration import confirmed_by_own
    from roadcollab.detection.detector import Detection

    def det(pos, kind="pothole", side="left"):
        return Detection(position=pos, side=side, kind=kind, depth=0.03, confidence=0.9)
    aided = [det(10.0), det(50.0), det(80.0, "bump"), det(120.0, side="right")]
    own = [det(10.8), det(80.2, "pothole"), det(119.0, side="both"), det(200.0)]
    assert confirmed_by_own(aided, own) == [aided[0], aided[3]]      # 50: no support; 80: other kind
    assert confirmed_by_own(aided, []) == []
    with pytest.raises(ParameterError, match="Detection objects"):
        confirmed_by_own(aided, ["x"])
