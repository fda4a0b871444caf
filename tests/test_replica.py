"""The replica attack (privacy.replica) and the composition of the Gaussian mechanism
(privacy.baselines.dp_composition)."""

import math

import numpy as np
import pytest

from roadcollab.errors import ParameterError
from roadcollab.experiments.config import ExperimentConfig
from roadcollab.experiments.security.replica_study import replica_messages
from roadcollab.experiments.security.segment import target_poles
from roadcollab.experiments.pipeline import PipelineCache
from roadcollab.experiments.security.study import AttackStudyConfig
from roadcollab.models.simulation import simulate_response
from roadcollab.privacy.attacks import pole_errors
from roadcollab.privacy.baselines.dp import DPSpec, gaussian_sigma
from roadcollab.privacy.baselines.dp_composition import composed_epsilon, composition_table, gaussian_epsilon
from roadcollab.privacy.replica import attack_replica, attack_replica_linked, replica_fit, replica_z
from roadcollab.privacy.physical_fit import _log_ratios


@pytest.fixture(scope="module")
def study():
    cfg = AttackStudyConfig()
    pipe = PipelineCache().pipeline(cfg.experiment, 0)
    return cfg, pipe, target_poles(pipe)


def _hardened_z(pipe, j, w, noise=None):
    est, g = pipe.estimators[j], pipe.grid
    y = simulate_response(est.true_plant, w)
    if noise is not None:
        y = y + noise
    return g.irfft(est.invert(g.rfft(y)))


def test_replica_z_reproduces_the_receivers_inversion(study):
    """Re-running the pipeline with the vehicle's own parameters gives its z to round-off."""
    cfg, pipe, _ = study
    g, est = pipe.grid, pipe.estimators[1]
    w = pipe.road(np.random.default_rng(3)).velocity
    Z = replica_z(w, g, _log_ratios(est.vehicle.true_params), _log_ratios(est.vehicle.estimated_params))
    z = _hardened_z(pipe, 1, w)
    assert np.max(np.abs(g.irfft(Z) - z)) < 1e-9 * np.max(np.abs(z))


def test_replica_recovers_noiseless_hardened_poles(study):
    cfg, pipe, targets = study
    w = pipe.road(np.random.default_rng(11)).velocity
    for j in (0, 2):
        poles = attack_replica(_hardened_z(pipe, j, w), w, pipe.grid, cfg.experiment.fleet.nominal)
        assert np.max(pole_errors(poles, targets[j])) < 1e-3


@pytest.mark.slow     # end-to-end replica attack over several segments (make test-slow)
def test_replica_linked_recovers_noisy_poles(study):
    cfg, pipe, targets = study
    rng = np.random.default_rng(12)
    segs = []
    for _ in range(2):
        w = pipe.road(rng).velocity
        n = cfg.experiment.sensor_noise_std * rng.standard_normal(w.shape)
        segs.append((_hardened_z(pipe, 1, w, n), w))
    poles = attack_replica_linked(segs, pipe.grid, cfg.experiment.fleet.nominal)
    assert np.max(pole_errors(poles, targets[1])) < 1e-2


@pytest.mark.slow     # end-to-end replica attack over several segments (make test-slow)
def test_replica_on_pure_noise_is_finite(study):
    cfg, pipe, _ = study
    rng = np.random.default_rng(13)
    g = pipe.grid
    fit = replica_fit([(rng.standard_normal((g.nfft, 2)), rng.standard_normal((g.n_samples, 2)))], g,
                      cfg.experiment.fleet.nominal, max_nfev=30)
    assert fit.poles.size in (0, 4)
    assert np.all(np.isfinite(fit.poles))
    assert np.all(np.isfinite(pole_errors(fit.poles, study[2][0]))) or fit.poles.size == 0


def test_replica_rejects_bad_arguments(study):
    cfg, pipe, _ = study
    g, nom = pipe.grid, cfg.experiment.fleet.nominal
    with pytest.raises(ParameterError, match="segments must not be empty"):
        replica_fit([], g, nom)
    with pytest.raises(ParameterError, match="grid must be a SegmentGrid"):
        attack_replica(np.zeros((10, 2)), np.zeros((10, 2)), "grid", nom)
    with pytest.raises(ParameterError, match=r"road_w must have at most"):
        attack_replica(np.zeros((10, 2)), np.zeros((g.nfft + 1, 2)), g, nom)
    with pytest.raises(ParameterError, match="nominal must be a HalfCarParameters"):
        attack_replica(np.zeros((10, 2)), np.zeros((10, 2)), g, None)


@pytest.mark.parametrize("eps", [0.5, 2.0, 10.0])
def test_single_gaussian_matches_balle_wang(eps):
    """n = 1: the accountant's epsilon of the noise gaussian_sigma calibrates is eps back."""
    m = gaussian_sigma(eps, 1e-5, 1.0)
    assert gaussian_epsilon(m, 1e-5) == pytest.approx(eps, rel=1e-9)
    assert composed_epsilon(m, 1, 1e-5) == pytest.approx(eps, rel=1e-4)
    assert composed_epsilon(m, 1, 1e-5, accountant="rdp") >= eps


@pytest.mark.parametrize("m, n", [(2.0, 10), (0.9, 4)])
def test_composition_is_one_gaussian_at_sigma_over_sqrt_n(m, n):
    """n Gaussians of multiplier m compose exactly to one of multiplier m / sqrt(n)."""
    pld = composed_epsilon(m, n, 1e-5)
    eps_exact = gaussian_epsilon(m / math.sqrt(n), 1e-5)
    assert pld == pytest.approx(eps_exact, rel=1e-4)
    # gaussian_sigma inverted at the composed level gives sigma / sqrt(n) back.
    assert gaussian_sigma(pld, 1e-5, 1.0) == pytest.approx(m / math.sqrt(n), rel=1e-4)
    assert composed_epsilon(m, n, 1e-5, accountant="exact") == pytest.approx(eps_exact, rel=1e-12)


def test_composition_grows_with_n():
    rows = composition_table(DPSpec(epsilons=(1.0, 10.0)), (1, 10, 100), accountant="exact")
    for eps in (1.0, 10.0):
        tot = [r["epsilon_total"] for r in rows if r["epsilon_per_message"] == eps]
        assert tot[0] == pytest.approx(eps, rel=1e-9)
        assert tot[0] < tot[1] < tot[2] <= 100 * eps
        # Advanced composition: growth about sqrt(n) for small per-message epsilon, never more than n.
        assert tot[2] > 3 * tot[0]


def test_composition_rejects_bad_arguments():
    with pytest.raises(ParameterError, match="n_messages"):
        composed_epsilon(1.0, 0, 1e-5)
    with pytest.raises(ParameterError, match="accountant must be one of"):
        composed_epsilon(1.0, 1, 1e-5, accountant="moments")
    with pytest.raises(ParameterError, match="delta"):
        composed_epsilon(1.0, 1, 1.5)


def test_replica_messages_are_what_the_attacker_sees():
    small = AttackStudyConfig(experiment=ExperimentConfig(n_vehicles=3, segment_length=100.0))
    seg = replica_messages(small, 0, 1, epsilons=(10.0,), n_targets=2)
    n = seg["grid"].n_samples
    assert set(seg["z"]) == {"hardened", "dp(eps=10)"} and len(seg["z"]["hardened"]) == 2
    # hardened z is each vehicle's own inversion; dp adds noise of the calibrated sigma (5 sigma bound on
    # the sample standard deviation of 2 x nfft draws)
    for j in range(2):
        assert np.array_equal(seg["z"]["hardened"][j], seg["z_all"][j])
        noise = seg["z"]["dp(eps=10)"][j] - seg["z"]["hardened"][j]
        sd = seg["sigmas"][10.0]
        assert abs(noise.std() / sd - 1) < 5 / math.sqrt(2 * noise.size)
    # the fused road is the mean of the *other* vehicles' posterior inversions, cut to N samples
    post = seg["post_all"]
    for j in range(2):
        others = np.delete(post, j, axis=0).mean(axis=0)[:n]
        np.testing.assert_allclose(seg["road"]["fused"][j], others, rtol=0, atol=1e-15 * np.abs(others).max())
    assert seg["road"]["true"][0].shape[1] == 2 and len(seg["targets"]) == 2
    # the same segment seed gives the same messages (the attack study's roads)
    again = replica_messages(small, 0, 1, epsilons=(10.0,), n_targets=2)
    assert np.array_equal(again["z"]["dp(eps=10)"][1], seg["z"]["dp(eps=10)"][1])


