"""Lemma 1 gain, the input observer (eq. 4) and their discretisation."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from roadcollab import HalfCarParameters, JDPNoise, ParameterError, build_road_input_estimator, half_car_model, \
    jdp_estimator_gain
from roadcollab.estimation.estimator import observer_corner

MODEL = half_car_model(HalfCarParameters())
NOISE = dict(wiener_cov=0.0057 * np.eye(2), jump_rate=0.3, jump_mean=[0.01, -0.005],
             jump_cov=np.array([[0.0036, 0.0012], [0.0012, 0.0036]]), measurement_cov=1.25e-5 * np.eye(2))


def _lemma1_pieces(model, noise):
    mu = np.asarray(noise["jump_mean"]).reshape(2, 1)
    Sb = noise["wiener_cov"] + noise["jump_rate"] * (mu @ mu.T) + noise["jump_rate"] * noise["jump_cov"]
    V2 = noise["measurement_cov"] + model.D @ Sb @ model.D.T
    V2i = np.linalg.inv(V2)
    V1 = model.B @ Sb @ model.B.T - model.B @ Sb @ model.D.T @ V2i @ model.D @ Sb @ model.B.T
    Abar = model.A - model.B @ Sb @ model.D.T @ V2i @ model.C
    return Sb, V1, V2, V2i, Abar


def test_gain_solves_the_riccati_equation_and_is_stabilising():
    from roadcollab.estimation.estimator import _jdp_gain

    F, Q = _jdp_gain(MODEL, JDPNoise(**NOISE))
    np.testing.assert_array_equal(F, jdp_estimator_gain(MODEL, **NOISE))
    Sb, V1, V2, V2i, Abar = _lemma1_pieces(MODEL, NOISE)
    B, C, D = MODEL.B, MODEL.C, MODEL.D
    res = Abar @ Q + Q @ Abar.T + V1 - Q @ C.T @ V2i @ C @ Q
    assert np.abs(res).max() < 1e-9 * np.abs(V1).max()
    np.testing.assert_allclose(F, -B @ Sb @ D.T @ V2i - Q @ C.T @ V2i, rtol=1e-12, atol=1e-14)
    assert np.linalg.eigvalsh(0.5 * (Q + Q.T)).min() > -1e-12 * np.abs(Q).max()
    assert np.linalg.eigvals(MODEL.A + F @ C).real.max() < 0


@given(st.floats(0.5, 2.0), st.floats(0.5, 2.0), st.floats(0.6, 1.6), st.floats(-3, 1))
def test_estimator_stable_for_random_plants_and_noise(ks, cs, mass, log_r):
    model = half_car_model(HalfCarParameters(stiffness=22e3 * ks, damping=1.8e3 * cs, sprung_mass=750 * mass))
    noise = dict(NOISE, measurement_cov=10.0**log_r * 1.25e-5 * np.eye(2))
    F = jdp_estimator_gain(model, **noise)
    assert np.linalg.eigvals(model.A + F @ model.C).real.max() < 0


def test_observer_equals_its_low_pass_transfer_function():
    est = build_road_input_estimator(MODEL, JDPNoise(**NOISE), gamma=3.0, dt=0.005)
    g = observer_corner(3.0)
    assert g == pytest.approx(6.0)                       # gamma (1 + gamma) / 2
    A, B, C = MODEL.A, MODEL.B, MODEL.C
    K = np.linalg.solve(B.T @ B, B.T)
    s = 2j * np.pi * np.logspace(-2, 2, 41)
    Dj = est.continuous_response(s)
    for sk, Dk in zip(s, Dj):
        xhat_from_y = np.linalg.solve(sk * np.eye(4) - A - est.F @ C, -est.F)   # (sI - A - FC)^-1 (-F)
        expect = g / (sk + g) * K @ (sk * np.eye(4) - A) @ xhat_from_y
        np.testing.assert_allclose(Dk, expect, rtol=1e-9, atol=1e-12)


def test_observer_step_response_is_first_order():
    # w_hat' = g (w_raw - w_hat): with the estimator state frozen at zero, a unit raw input
    # gives 1 - exp(-g t). Check on the observer block of the realisation.
    est = build_road_input_estimator(MODEL, JDPNoise(**NOISE), gamma=3.0, dt=0.005)
    obs = est.Ac[4:, 4:]
    np.testing.assert_allclose(obs, -6.0 * np.eye(2))


@pytest.mark.parametrize("gamma", [1.0, 8.0, 32.0, 512.0])
def test_discretisation_matches_continuous_design_without_lag(gamma):
    """Bilinear map vs the continuous design, 200 Hz: within 2 % and 2 degrees up to 10 Hz.

    Measured for the default gamma = 512 (largest over entries, magnitude / phase): 10 Hz
    0.03 % / 0.13 deg, 20 Hz 0.2 % / 0.6 deg, 30 Hz 0.9 % / 1.7 deg, 40 Hz 3.0 % / 3.7 deg
    (frequency warping). A zero-order hold on y added half a sample of delay: 9 degrees at 10 Hz.
    """
    dt = 0.005
    est = build_road_input_estimator(MODEL, JDPNoise(**NOISE), gamma=gamma, dt=dt)
    f = np.linspace(0.2, 10.0, 50)
    Dd = est.frequency_response(2 * np.pi * f * dt)
    Dc = est.continuous_response(2j * np.pi * f)
    big = np.abs(Dc) > 1e-3 * np.abs(Dc).max(axis=(1, 2), keepdims=True)
    assert np.max(np.abs(np.abs(Dd[big]) / np.abs(Dc[big]) - 1)) < 0.02
    assert np.max(np.abs(np.degrees(np.angle(Dd[big] / Dc[big])))) < 2.0
    # Feed-through: w_hat[k] uses y[k].
    assert np.max(np.abs(est.Dd)) > 0


def test_online_estimate_peaks_at_lag_zero_against_the_truth():
    """The causal online estimate is aligned with the road velocity it estimates."""
    from roadcollab.models.road import RoadSpec, generate_road
    from roadcollab.models.simulation import discretize_plant, simulate_response

    dt = 0.005
    est = build_road_input_estimator(MODEL, JDPNoise(**NOISE), gamma=512.0, dt=dt)
    road = generate_road(RoadSpec(length=300.0, anomaly_density=0.0), rng=4).sample(15.0, 1 / dt)
    w = road.velocity
    y = simulate_response(discretize_plant(MODEL, dt), w)
    w_hat = est.filter(y, include_bias=False)
    a, b = w[400:, 0] - w[400:, 0].mean(), w_hat[400:, 0] - w_hat[400:, 0].mean()
    lags = np.arange(-5, 6)
    xc = [np.dot(a[10:-10], np.roll(b, -k)[10:-10]) for k in lags]
    ac = [np.dot(a[10:-10], np.roll(a, -k)[10:-10]) for k in lags]
    assert lags[int(np.argmax(xc))] == 0
    # The shape around the peak is the road's own autocorrelation (tyre enveloping smooths it
    # over about 3 samples): a lag of one sample would move it by a whole step.
    for k in (4, 6):
        assert abs(xc[k] / xc[5] - ac[k] / ac[5]) < 0.05


def test_discrete_filter_is_causal_and_agrees_with_the_grid():
    dt = 0.005
    est = build_road_input_estimator(MODEL, JDPNoise(**NOISE), gamma=8.0, dt=dt)
    # The causal filter and the DFT-grid application agree for a zero-padded input.
    # The estimator has a slow pole (about -0.03 rad/s, mirroring the plant's zeros at DC), so
    # the padding must cover many time constants for the circular and linear results to meet.
    rng = np.random.default_rng(0)
    n = 200_000
    y = np.vstack([rng.standard_normal((500, 2)), np.zeros((n - 500, 2))])
    causal = est.filter(y, include_bias=False)
    Y = np.fft.rfft(y, axis=0)
    H = est.frequency_response(2 * np.pi * np.fft.rfftfreq(n))
    grid = np.fft.irfft(np.einsum("kij,kj->ki", H, Y), n=n, axis=0)
    np.testing.assert_allclose(causal[:3000], grid[:3000], atol=1e-8 * np.abs(causal).max())


def test_bias_term_gives_the_mean_road_velocity_offset():
    est = build_road_input_estimator(MODEL, JDPNoise(**NOISE), gamma=8.0, dt=0.005)
    # The constant (B + F D) lambda mu drive with y = 0: the observer's steady output.
    # Closed form: the estimate of a road seen only through y = 0 settles at the prior mean
    # road velocity lambda * mu_eta.
    lam_mu = NOISE["jump_rate"] * np.asarray(NOISE["jump_mean"])
    np.testing.assert_allclose(est.steady_offset(), lam_mu, rtol=1e-9)
    out = est.filter(np.zeros((200_000, 2)))   # 1000 s: many slow time constants
    np.testing.assert_allclose(out[-1], lam_mu, rtol=1e-6)


@pytest.mark.parametrize("kw,match", [
    (dict(measurement_cov=np.zeros((2, 2))), "measurement_cov must be positive definite"),
    (dict(wiener_cov=np.eye(3)), r"wiener_cov must have shape \(2, 2\), got \(3, 3\)"),
    (dict(jump_rate=-1.0), "jump_rate must be >= 0, got -1"),
    (dict(jump_cov=[[1.0, 2.0], [0.0, 1.0]]), "jump_cov must be symmetric"),
    (dict(jump_mean=[np.nan, 0.0]), "jump_mean must be finite"),
])
def test_bad_noise_statistics_are_refused(kw, match):
    with pytest.raises(ParameterError, match=match):
        jdp_estimator_gain(MODEL, **dict(NOISE, **kw))


def test_bad_estimator_arguments():
    with pytest.raises(ParameterError, match="gamma must be > 0, got -1"):
        build_road_input_estimator(MODEL, JDPNoise(**NOISE), gamma=-1.0, dt=0.005)
    with pytest.raises(ParameterError, match="dt must be > 0, got 0"):
        build_road_input_estimator(MODEL, JDPNoise(**NOISE), gamma=1.0, dt=0.0)
    est = build_road_input_estimator(MODEL, JDPNoise(**NOISE), gamma=1.0, dt=0.005)
    with pytest.raises(ParameterError, match=r"y must have shape \(any, 2\), got \(10, 3\)"):
        est.filter(np.zeros((10, 3)))
