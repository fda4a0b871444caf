"""Attacks on the exchanges, and the study that runs them."""

import numpy as np
import pytest

from roadcollab import ExperimentConfig, sample_fleet
from roadcollab.experiments.pipeline import FleetPipeline
from roadcollab.privacy.obfuscation import obfuscate
from roadcollab.privacy.attacks import (PhysicalPrior, attack_model_reduction, attack_multiplicity, attack_pole_intersection, attack_signals_prior, pole_errors, select_by_prior)
from roadcollab.experiments.security.study import AttackStudyConfig, run_attack_study
from roadcollab.experiments.security.tables import _linkability
from roadcollab.models.simulation import add_sensor_noise, simulate_response

CFG = ExperimentConfig(n_vehicles=3, n_runs=1, segment_length=120.0)
PIPE = FleetPipeline(CFG, sample_fleet(3, CFG.fleet, rng=21))


def _messages(seed):
    g = PIPE.grid
    rng = np.random.default_rng(seed)
    road = PIPE.road(rng)
    e = PIPE.estimators[0]
    y = add_sensor_noise(simulate_response(e.true_plant, road.velocity), 0.05, rng=rng)
    res = e.estimate(y)
    plain = e.message(res)
    paper, _, _ = obfuscate(plain, g, CFG.obfuscation, rng=rng, T_response=e.T_ss_f, S_response=e.S_ss_f)
    return e, plain, paper, e.hardened_message(res), road


def test_pole_errors_use_optimal_matching():
    true = np.array([-1 + 5j, -1 - 5j, -2 + 8j, -2 - 8j])
    est = true[::-1] * (1 + np.array([0.0, 0.005, 0.0, 0.02]))
    err = pole_errors(est, true)
    np.testing.assert_allclose(np.sort(err), [0, 0, 0.005, 0.02], atol=1e-12)
    assert np.all(np.isinf(pole_errors([], true)))
    assert np.isinf(pole_errors(true[:2], true)).sum() == 2


def test_prior_selects_suspension_like_pairs():
    cands = np.array([-100.0, -3 + 9j, -3 - 9j, -40 + 10j, -1.5 + 6j, -0.01 + 5j])
    sel = select_by_prior(cands, PhysicalPrior())
    assert set(np.round(sel, 6)) == {-3 + 9j, -3 - 9j, -1.5 + 6j, -1.5 - 6j}


def test_attacks_read_the_clear_message_exactly():
    e, plain, _, _, _ = _messages(1)
    true = e.S_ss.continuous_poles()
    for attack in (attack_model_reduction, attack_pole_intersection, attack_multiplicity):
        assert np.max(pole_errors(attack(plain), true)) < 1e-6


@pytest.mark.parametrize("seed", [2, 3, 4])
def test_paper_mechanism_beats_model_reduction_but_not_the_informed_attacks(seed):
    e, _, paper, _, _ = _messages(seed)
    true = e.S_ss.continuous_poles()
    # The paper's attack fails (Figs. 8-10) ...
    assert np.median(pole_errors(attack_model_reduction(paper), true)) > 0.01
    # ... the structural one does not: Psi's poles are double, the vehicle's are simple.
    assert np.max(pole_errors(attack_multiplicity(paper), true)) < 1e-6


def test_hardened_message_carries_no_dynamics_and_signal_attack_reports_failure_cleanly():
    e, _, _, hard, road = _messages(5)
    assert not hasattr(hard, "T") and hard.z.shape == (PIPE.grid.nfft, 2)
    g = PIPE.grid
    w_band = g.irfft(g.weight[:, None] * g.rfft(road.velocity))
    est = attack_signals_prior(hard.z, w_band, g.dt)
    assert est.size % 2 == 0
    assert np.all(np.isfinite(pole_errors(est, e.S_ss.continuous_poles())) | (est.size < 4))


def test_linkability_oracles():
    rng = np.random.default_rng(0)
    same = {(v, r): np.array([v, 2.0 * v]) + 1e-3 * rng.standard_normal(2) for v in range(5) for r in range(3)}
    out = _linkability(same)
    assert out["auc"] == pytest.approx(1.0) and out["top1_accuracy"] == 1.0
    noise = {(v, r): rng.standard_normal(3) for v in range(6) for r in range(6)}
    out = _linkability(noise)
    assert 0.35 < out["auc"] < 0.65


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_study_smoke():
    cfg = AttackStudyConfig(experiment=ExperimentConfig(n_vehicles=4, n_runs=1, segment_length=120.0), n_runs=2,
                            paillier_bits=512, paillier_sample=4, physical_fit_runs=1, dp_epsilons=(1.0,),
                            replica_runs=1, replica_targets=1, poisoning_runs=1, secagg_min_inputs=2,
                            secagg_colluders=(1,))
    res = run_attack_study(cfg, 3)
    keys = {(r.mechanism, r.attack) for r in res.attack_rows}
    for mech in ("paper", "hardened"):
        for attack in ("model_reduction", "pole_intersection"):
            assert (mech, attack) in keys
    for mech in ("none", "paper", "paper_vehicle", "hardened", "dp(eps=1)", "fused", "secure_aggregation"):
        assert (mech, "replica") in keys, mech
    assert ("secure_aggregation", "replica_collusion_c3") in keys      # n - 1 colluders: the edge case
    # The active aggregator's attacks recover nothing: each row scores the honest aggregate's fit.
    agg = next(r for r in res.attack_rows if (r.mechanism, r.attack) == ("secure_aggregation", "replica"))
    for attack in ("differencing", "equivocation", "sybil", "key_substitution"):
        row = next(r for r in res.attack_rows if (r.mechanism, r.attack) == ("secure_aggregation", attack))
        assert (row.median_rel_pole_error, row.success_rate) == (agg.median_rel_pole_error, agg.success_rate)
    assert all(r.max_rel_diff < 1e-9 for r in res.exactness_rows)
    assert "secure_aggregation" in [r.mechanism for r in res.exactness_rows]
    names = [r.mechanism for r in res.baseline_rows]
    assert names[:3] == ["none", "paper", "hardened"] and {"he", "aead", "secure_aggregation"} <= set(names)
    dp = next(r for r in res.baseline_rows if r.mechanism.startswith("dp"))
    none = res.baseline_rows[0]
    assert dp.mse_vehicle1 == pytest.approx(none.mse_vehicle1)   # vehicle 1 receives nothing
    assert dp.mse_vehicle2 > none.mse_vehicle2                     # noise costs accuracy
    targets = {r.target for r in res.poisoning_rows}
    assert {"receiver_none", "receiver_hardened", "fused_mean", "fused_robust"} <= targets
    assert all(r.max_ratio_to_observer <= 2 for r in res.poisoning_rows if r.target.startswith("receiver"))
    assert [r.segments for r in res.composition_rows] == [1, 3, 10, 100]
    assert {p.mechanism for p in res.frontier} >= {"none", "hardened", "secure_aggregation"}
