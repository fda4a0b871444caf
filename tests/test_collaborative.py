"""Algorithm 1 (eqs. 11-12) and Algorithm 2 (Theorem 1) on a small fleet."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roadcollab import CollaborativeEstimator, learning_filters, ExperimentConfig, MessageError, ObfuscationSpec, ParameterError, \
    obfuscate, run_reproduction, sample_fleet
from roadcollab.experiments.pipeline import FleetPipeline
from roadcollab.privacy.obfuscation import draw_obfuscator
from roadcollab.models.simulation import add_sensor_noise, simulate_response
from roadcollab.lti.batch2x2 import inv2x2, matvec
from roadcollab.models.vehicle import FleetSpec

CFG = ExperimentConfig(n_vehicles=3, n_runs=1, segment_length=120.0, margin=15.0)


@pytest.fixture(scope="module")
def pipe():
    return FleetPipeline(CFG, sample_fleet(3, CFG.fleet, rng=11))


def _measure(pipe, seed, noise=0.05):
    rng = np.random.default_rng(seed)
    road = pipe.road(rng)
    ys = [add_sensor_noise(simulate_response(e.true_plant, road.velocity), noise, rng=rng) for e in pipe.estimators]
    return road, ys


def _rel(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


def test_algorithm1_equals_the_complementary_blend(pipe):
    """Complementary blend: w_hat_j = D_j y_j + (I - D_j P_hat_j) W_reg P_hat_{j-1}^-1 y_{j-1}."""
    g = pipe.grid
    _, ys = _measure(pipe, 1)
    e1, e2, e3 = pipe.estimators
    r1 = e1.estimate(ys[0])
    r2 = e2.estimate(ys[1], e1.message(r1), unguarded=True)
    r3 = e3.estimate(ys[2], e2.message(r2), unguarded=True)
    for prev, cur, y_prev, y_cur, r in ((e1, e2, ys[0], ys[1], r2), (e2, e3, ys[1], ys[2], r3)):
        Y_prev, Y = g.rfft(y_prev), g.rfft(y_cur)
        Z = np.zeros_like(Y_prev)                                 # W_reg P_hat_{j-1}^-1 y_{j-1}
        Z[g.active] = g.reg_weight[g.active, None] * np.linalg.solve(prev.P_f[g.active], Y_prev[g.active][..., None])[..., 0]
        blend = matvec(cur.D_f, Y)
        blend += matvec(np.eye(2) - cur.D_f @ cur.P_f, Z)
        expect = g.irfft(blend, g.n_samples) + cur.estimator.steady_offset()
        assert _rel(r.estimate, expect) < 1e-9
    # Vehicle 1 has w^f = 0: its estimate is its observer.
    np.testing.assert_array_equal(r1.estimate, r1.observer_only)


def test_learning_filters_equal_minus_Sinv_T_z(pipe):
    g = pipe.grid
    _, ys = _measure(pipe, 2)
    e1, e2, e3 = pipe.estimators
    m1 = e1.message(e1.estimate(ys[0]))
    r2 = e2.estimate(ys[1], m1, unguarded=True)
    m2 = e2.message(r2)
    act = g.active
    T_prev, S_prev = m2.T.frequency_response(g.omega_dt[act]), m2.S.frequency_response(g.omega_dt[act])
    Z = g.reg_weight[act, None] * matvec(inv2x2(T_prev), g.rfft(m2.e)[act] - matvec(S_prev, g.rfft(m2.wf)[act]))
    Wf = e3.learn(m2)[act]
    expect = matvec(-inv2x2(e3.S_f[act]) @ e3.T_f[act], Z)
    assert np.max(np.abs(Wf - expect)) < 1e-9 * np.max(np.abs(expect))
    # The explicit filters of eqs. 11-12 give the same update.
    L1, L2 = learning_filters(e3.T_f[act], e3.S_f[act], T_prev, S_prev, g.reg_weight[act])
    explicit = matvec(L1, g.rfft(m2.wf)[act]) + matvec(L2, g.rfft(m2.e)[act])
    assert np.max(np.abs(Wf - explicit)) < 1e-9 * np.max(np.abs(expect))


@settings(max_examples=8)
@given(st.integers(0, 2**32 - 1))
def test_theorem1_privacy_changes_no_estimate(seed):
    pipe = _PIPE
    g = pipe.grid
    _, ys = _measure(pipe, seed)
    rng = np.random.default_rng(seed)
    plain = priv = None
    for e, y in zip(pipe.estimators, ys):
        r, rp = e.estimate(y, plain, unguarded=True), e.estimate(y, priv, unguarded=True)
        assert _rel(rp.estimate, r.estimate) < 1e-9
        plain = e.message(r)
        priv, _, _ = obfuscate(e.message(rp), g, ObfuscationSpec(), rng=rng,
                               T_response=e.T_ss_f, S_response=e.S_ss_f)
        assert priv.mechanism == "paper"
        # The sent systems are not the clear ones: their responses differ by Psi.
        om = g.omega_dt[g.active][::50]
        assert _rel(priv.T.frequency_response(om), plain.T.frequency_response(om)) > 1e-3


_PIPE = FleetPipeline(CFG, sample_fleet(3, CFG.fleet, rng=11))


def test_obfuscated_realisation_shows_no_block_of_T(pipe):
    g = pipe.grid
    e = pipe.estimators[0]
    _, ys = _measure(pipe, 3)
    msg, psi1, psi2 = obfuscate(e.message(e.estimate(ys[0])), g, rng=4)
    n_t = e.T_ss.order
    assert msg.T.order == n_t + 2 * psi1.order
    # A series realisation would have an exactly zero off-diagonal block; a random orthogonal
    # similarity leaves none, and T's A matrix does not appear as a sub-block.
    assert np.min(np.abs(msg.T.A)) > 0
    assert not np.allclose(msg.T.A[:n_t, :n_t], e.T_ss.A)
    # Same transfer matrix as Psi1 T (on a few bins, away from the DC zeros).
    om = g.omega_dt[(g.freqs > 2) & (g.freqs < 40)][::40]
    expect = psi1.system.frequency_response(om) @ e.T_ss.frequency_response(om)
    assert _rel(msg.T.frequency_response(om), expect) < 1e-8


def test_balanced_similarity_keeps_a_high_gain_series_transfer_matrix():
    """Closed form: two diagonal systems with poles near z = 1 and gains 1e3, in series."""
    from roadcollab.lti.realisation import StateSpaceData, random_orthogonal, series, similarity

    rng = np.random.default_rng(5)
    z = np.exp(1j * np.geomspace(2e-3, 0.5, 60))

    def diag_system(poles, gain):
        B, C = rng.standard_normal((poles.size, 2)), gain * rng.standard_normal((2, poles.size))
        D = rng.standard_normal((2, 2))
        H = np.einsum("in,kn,nj->kij", C, 1 / (z[:, None] - poles[None, :]), B) + D
        return StateSpaceData(np.diag(poles), B, C, D, 0.005), H

    first, H1 = diag_system(1 - np.geomspace(3e-3, 0.3, 5), 1e3)
    second, H2 = diag_system(1 - np.geomspace(5e-3, 0.5, 4), 1.0)
    sys = series(first, second)
    hidden = similarity(sys, random_orthogonal(sys.order, rng), balance=True)
    assert np.max(np.abs(sys.A)) > 1e2           # the coupling block is large ...
    assert np.max(np.abs(hidden.A)) < 10         # ... and balancing removed it before hiding
    expect = H2 @ H1
    got = hidden.frequency_response(np.angle(z))
    assert _rel(got, expect) < 1e-10
    # The balancing is scipy's matrix_balance bit for bit (similarity calls its LAPACK routine directly).
    import scipy.linalg

    Q = random_orthogonal(sys.order, rng)
    Ab, (scale, _) = scipy.linalg.matrix_balance(sys.A, permute=False, separate=True)
    ref = (Q.T @ Ab @ Q, Q.T @ (sys.B / scale[:, None]), (sys.C * scale[None, :]) @ Q)
    assert all(np.array_equal(a, b) for a, b in zip((lambda h: (h.A, h.B, h.C))(similarity(sys, Q, balance=True)), ref))


@settings(max_examples=25)
@given(st.integers(0, 2**32 - 1))
def test_obfuscators_are_stable_invertible_and_well_conditioned(seed):
    spec = ObfuscationSpec()
    g = _PIPE.grid
    psi = draw_obfuscator(spec, g, rng=seed)
    assert spec.order_range[0] <= psi.order <= spec.order_range[1]
    assert np.all(psi.poles.real < 0)
    assert np.max(psi.zeros().real) <= -spec.min_zero_distance
    assert np.max(np.abs(psi.system.poles())) < 1
    H = psi.system.frequency_response(g.omega_dt[g.active])
    sv = np.linalg.svd(H, compute_uv=False)
    assert np.max(sv[:, 0] / sv[:, -1]) <= spec.max_condition


@settings(max_examples=30)
@given(st.integers(0, 2**32 - 1))
def test_condition_check_of_a_draw_equals_the_svd_of_its_numerators_on_the_warped_axis(seed):
    """The check decides on ``max_w cond N(j w)`` from powers of ``w`` and ``r = F / (2 |det|)``;
    here ``N(j w)`` is evaluated by ``np.polyval`` at complex ``s`` and conditioned by an SVD."""
    from roadcollab.privacy.obfuscator_design import _max_condition_on_axis, _warped_powers

    rng = np.random.default_rng(seed)
    g = _PIPE.grid
    n = int(rng.integers(1, 5))
    num = rng.standard_normal((2, 2, n + 1)) * np.exp(rng.uniform(-3, 3, (2, 2, 1)))
    om = np.minimum(g.omega_dt[g.active], np.pi * (1 - 1e-9))
    s = 1j * (2.0 / g.dt) * np.tan(om / 2)
    N = np.stack([[np.polyval(num[a, b], s) for b in range(2)] for a in range(2)]).transpose(2, 0, 1)
    sv = np.linalg.svd(N, compute_uv=False)
    expect = np.max(sv[:, 0] / sv[:, 1])
    got = _max_condition_on_axis(num, _warped_powers(g, 4))
    assert abs(got - expect) <= 1e-9 * expect


def test_condition_check_is_infinite_where_the_numerator_is_singular():
    from roadcollab.privacy.obfuscator_design import _max_condition_on_axis, _warped_powers

    P = _warped_powers(_PIPE.grid, 4)
    rank_one = np.array([[[1.0, 2.0, 3.0], [2.0, 4.0, 6.0]], [[0.5, 1.0, 1.5], [1.0, 2.0, 3.0]]])
    assert _max_condition_on_axis(rank_one, P) == np.inf
    assert _max_condition_on_axis(np.zeros((2, 2, 3)), P) == np.inf
    assert _max_condition_on_axis(np.eye(2)[:, :, None] * np.array([1.0, 5.0]), P) == pytest.approx(1.0)


def test_exact_models_without_noise_reconstruct_from_vehicle_2():
    """Oracle-free, noise-free, exact parameters: measured NMSE about 1e-6 from vehicle 2 on
    (edge effects of the offline filters); the bound asserted is 1e-4."""
    cfg = dataclasses.replace(CFG, n_vehicles=3, n_runs=2, sensor_noise_std=0.0,
                              fleet=FleetSpec(estimate_uncertainty=0.0))
    rows = run_reproduction(cfg, 5, privacy=False).table()
    assert rows[0].nmse_mean > 10 * max(r.nmse_mean for r in rows[1:])   # the causal observer is not exact
    for r in rows[1:]:
        assert r.nmse_mean < 1e-4


def test_same_seed_same_outputs_and_different_seed_differs():
    cfg = dataclasses.replace(CFG, n_runs=2)
    a, b, c = (run_reproduction(cfg, s).table() for s in (9, 9, 10))
    assert a == b
    assert a != c


def test_message_for_another_grid_is_refused(pipe):
    e = pipe.estimators[1]
    _, ys = _measure(pipe, 6)
    m = pipe.estimators[0].message(pipe.estimators[0].estimate(ys[0]))
    bad = dataclasses.replace(m, e=m.e[:-2], wf=m.wf[:-2])
    with pytest.raises(MessageError, match="message signals must have shape"):
        e.estimate(ys[1], bad, unguarded=True)
    with pytest.raises(ParameterError, match=r"y must have shape \(any, 2\), got \(5, 3\)"):
        e.estimate(np.zeros((5, 3)))
    with pytest.raises(ParameterError, match="y must have .* samples"):
        e.estimate(np.zeros((5, 2)))
    with pytest.raises(ParameterError, match="vehicle must be a Vehicle"):
        CollaborativeEstimator("car", CFG.noise_model(), pipe.grid, gamma=1.0)


def test_theorem1_holds_with_a_channel_reused_over_segments():
    from roadcollab.privacy.obfuscation import ObfuscationChannel

    pipe = _PIPE
    g = pipe.grid
    e1, e2 = pipe.estimators[:2]
    ch = ObfuscationChannel.draw(e1.T_ss, e1.S_ss, g, ObfuscationSpec(), rng=3)
    for seed in (1, 2):
        _, ys = _measure(pipe, seed)
        m1 = e1.message(e1.estimate(ys[0]))
        priv, psi1, _ = obfuscate(m1, g, rng=seed, T_response=e1.T_ss_f, S_response=e1.S_ss_f, channel=ch)
        assert priv.T is ch.T and psi1 is ch.psi1
        assert _rel(e2.estimate(ys[1], priv, unguarded=True).estimate,
                    e2.estimate(ys[1], m1, unguarded=True).estimate) < 1e-9
