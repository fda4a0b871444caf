"""Tests of roadcollab.privacy.baselines: Gaussian-mechanism DP, Paillier cost, ChaCha20-Poly1305 channel."""

from __future__ import annotations

import math
import time
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from phe import paillier
from scipy.stats import norm

from roadcollab.privacy.baselines import (
    AEAD_OVERHEAD_BYTES,
    DPSpec,
    aead_cost,
    classic_gaussian_sigma,
    dp_message,
    dp_sigmas,
    gaussian_sigma,
    l2_sensitivity,
    median_ms,
    new_key,
    open_sealed,
    paillier_cost,
    seal,
)
from roadcollab.privacy.baselines.paillier_packed import encrypt_packed, pack, precompute_rn, slot_layout, unpack
from roadcollab.errors import MessageError, ParameterError
from roadcollab.wire.message import InversionMessage
from roadcollab.wire.protocol import encode, inversion_nbytes
from roadcollab.estimation.grid import SegmentGrid
from roadcollab.lti.batch2x2 import inv2x2, matvec

HYP = settings(database=None, deadline=None, max_examples=60)


# -------------------------------------------------------------------------------------------
# helpers
# -------------------------------------------------------------------------------------------
def tiny_grid() -> SegmentGrid:
    # nfft = 24, 13 rfft bins at 0, 5/12, ..., 5 Hz; W(f) = 1 / (1 + (1/f)^4), W(0) = 0.
    return SegmentGrid(n_samples=16, sample_rate=10.0, band_low_hz=1.0, band_order=2, regularization_low_hz=1.0)


def fake_estimator(P_f: np.ndarray, grid: SegmentGrid) -> SimpleNamespace:
    return SimpleNamespace(P_f=P_f, grid=grid)


def release(est, y: np.ndarray) -> np.ndarray:
    """The released map z = W P^-1 y per bin on the padded grid (as CollaborativeEstimator.invert)."""
    g = est.grid
    Y = g.rfft(y)
    act = g.active
    Z = np.zeros_like(Y)
    Z[act] = g.reg_weight[act, None] * matvec(inv2x2(est.P_f[act]), Y[act])
    return g.irfft(Z)


def random_plant(grid: SegmentGrid, rng) -> np.ndarray:
    K = grid.n_bins
    P = rng.standard_normal((K, 2, 2)) + 1j * rng.standard_normal((K, 2, 2))
    # Real blocks at DC and Nyquist, as for a real-coefficient system.
    P[0] = P[0].real
    P[-1] = P[-1].real
    return P


def hardened(z: np.ndarray, mechanism: str = "hardened") -> InversionMessage:
    return InversionMessage(mechanism=mechanism, sample_rate=200.0, n_samples=z.shape[0] - 8, z=z, count=1)


# -------------------------------------------------------------------------------------------
# timing
# -------------------------------------------------------------------------------------------
def test_median_ms_measures_milliseconds():
    calls = []
    t = median_ms(lambda: (calls.append(1), time.sleep(0.003)), 3)
    assert len(calls) == 3
    assert 3.0 <= t < 500.0          # sleep guarantees at least 3 ms; the upper bound is generous


@pytest.mark.parametrize("fn, repeats", [(lambda: None, 0), (lambda: None, 1.5), ("not callable", 3)])
def test_median_ms_rejects_bad_arguments(fn, repeats):
    with pytest.raises(ParameterError):
        median_ms(fn, repeats)


# -------------------------------------------------------------------------------------------
# DP: specification and sensitivity
# -------------------------------------------------------------------------------------------
def test_dpspec_defaults_and_validation():
    s = DPSpec()
    assert s.epsilons == (0.5, 1.0, 2.0, 5.0, 10.0) and s.delta == 1e-5 and s.rho == 0.5
    assert DPSpec(epsilons=[1, 2]).epsilons == (1.0, 2.0)
    for bad in (dict(epsilons=(1.0, 0.0)), dict(epsilons=()), dict(epsilons=3.0), dict(delta=0.0),
                dict(delta=1.0), dict(rho=0.0), dict(rho=-1.0)):
        with pytest.raises(ParameterError):
            DPSpec(**bad)
    with pytest.raises(ParameterError, match="rho"):
        DPSpec(rho=-1.0)


def test_sensitivity_of_a_diagonal_system_by_hand():
    g = tiny_grid()
    P = np.tile(np.diag([2.0, 4.0]).astype(complex), (g.n_bins, 1, 1))   # gain W_k * max(1/2, 1/4) <= 0.5
    P[0] = 0.0                                  # singular at DC, where W = 0: must be ignored
    P[3] = np.diag([0.25, 4.0])                 # f = 1.25 Hz: gain W_3 * 4
    P[12] = np.diag([2.0, -0.5j])               # f = 5 Hz: gain W_12 * 2 (smaller than bin 3)
    W3 = 1.0 / (1.0 + (1.0 / 1.25) ** 4)        # = 1 / 1.4096
    rho = 0.5
    expected = rho * 4.0 / 1.4096
    assert math.isclose(W3, 1 / 1.4096, rel_tol=1e-15)
    assert math.isclose(l2_sensitivity(fake_estimator(P, g), rho), expected, rel_tol=1e-13)
    # Linear in rho.
    assert math.isclose(l2_sensitivity(fake_estimator(P, g), 2.0), 4 * expected, rel_tol=1e-13)


def test_sensitivity_closed_form_matches_svd():
    g = tiny_grid()
    rng = np.random.default_rng(3)
    for _ in range(20):
        P = random_plant(g, rng)
        act = g.active
        sv = np.linalg.svd(g.reg_weight[act, None, None] * np.linalg.inv(P[act]), compute_uv=False)
        assert math.isclose(l2_sensitivity(fake_estimator(P, g), 1.0), sv[:, 0].max(), rel_tol=1e-10)


def test_sensitivity_bounds_the_release_and_is_attained_on_the_periodic_grid():
    g = tiny_grid()
    rng = np.random.default_rng(4)
    P = random_plant(g, rng)
    est = fake_estimator(P, g)
    gain = l2_sensitivity(est, 1.0)
    # Any pair of records (N samples, zero-padded): ||z - z'|| <= gain * ||y - y'||.
    for _ in range(200):
        dy = rng.standard_normal((g.n_samples, 2))
        assert np.linalg.norm(release(est, dy)) <= gain * np.linalg.norm(dy) * (1 + 1e-12)
    # A tone at the worst bin along its top right singular vector attains the bound (nfft samples).
    act = np.flatnonzero(g.active)
    M = g.reg_weight[act, None, None] * np.linalg.inv(P[act])
    _, s, Vh = np.linalg.svd(M)
    i = int(np.argmax(s[:, 0]))
    k, v = act[i], Vh[i, 0].conj()
    n = np.arange(g.nfft)
    dy = np.real(np.exp(2j * np.pi * k * n / g.nfft)[:, None] * v[None, :])
    ratio = np.linalg.norm(release(est, dy)) / np.linalg.norm(dy)
    assert math.isclose(ratio, gain, rel_tol=1e-9)


def test_sensitivity_rejects_bad_arguments():
    g = tiny_grid()
    P = random_plant(g, np.random.default_rng(5))
    with pytest.raises(ParameterError, match="rho"):
        l2_sensitivity(fake_estimator(P, g), 0.0)
    with pytest.raises(ParameterError, match="P_f"):
        l2_sensitivity(fake_estimator(P[:-1], g), 1.0)
    with pytest.raises(ParameterError):
        l2_sensitivity(object(), 1.0)
    P[4] = np.array([[1.0, 2.0], [2.0, 4.0]])          # singular at an active bin
    with pytest.raises(ParameterError, match="singular"):
        l2_sensitivity(fake_estimator(P, g), 1.0)


@pytest.fixture(scope="module")
def vehicle():
    from roadcollab import ExperimentConfig, sample_fleet
    from roadcollab.experiments.pipeline import FleetPipeline

    cfg = ExperimentConfig(n_vehicles=1, n_runs=1, segment_length=60.0, margin=15.0)
    return FleetPipeline(cfg, sample_fleet(1, cfg.fleet, rng=11)).estimators[0]


def test_sensitivity_of_a_real_vehicle_bounds_its_hardened_messages(vehicle):
    est = vehicle
    g = est.grid
    rho = 0.5
    sens = l2_sensitivity(est, rho)
    rng = np.random.default_rng(6)
    y = rng.standard_normal((g.n_samples, 2))
    z = est.hardened_message(est.estimate(y)).z

    def z_of(dy):
        dy = rho * dy / np.linalg.norm(dy)
        return est.hardened_message(est.estimate(y + dy)).z

    for _ in range(5):
        assert np.linalg.norm(z_of(rng.standard_normal(y.shape)) - z) <= sens * (1 + 1e-9)
    # Worst case: a tone at the worst bin along its top right singular vector, on N samples only
    # (zero padding), comes close to the bound and never exceeds it. The worst bin lies near the
    # regulariser's 0.25 Hz corner, where a 20 s window holds only a few periods and leaks into
    # neighbouring bins: measured 0.89 of the bound.
    act = np.flatnonzero(g.active)
    _, s, Vh = np.linalg.svd(g.reg_weight[act, None, None] * inv2x2(est.P_f[act]))
    i = int(np.argmax(s[:, 0]))
    n = np.arange(g.n_samples)
    tone = np.real(np.exp(2j * np.pi * act[i] * n / g.nfft)[:, None] * Vh[i, 0].conj()[None, :])
    dist = np.linalg.norm(z_of(tone) - z)
    assert 0.8 * sens <= dist <= sens * (1 + 1e-9)
    sig = dp_sigmas(est, DPSpec())
    assert list(sig) == list(DPSpec().epsilons)
    assert all(math.isclose(sig[e], gaussian_sigma(e, 1e-5, sens)) for e in sig)
    assert all(a > b for a, b in zip(list(sig.values()), list(sig.values())[1:]))


# -------------------------------------------------------------------------------------------
# DP: analytic Gaussian mechanism
# -------------------------------------------------------------------------------------------
def agm_condition(eps: float, delta: float, s: float, D: float) -> float:
    """Left-hand side of Balle and Wang's condition (Theorem 8), evaluated directly."""
    return norm.cdf(D / (2 * s) - eps * s / D) - math.exp(eps) * norm.cdf(-D / (2 * s) - eps * s / D)


def delta0(eps: float) -> float:
    return 0.5 - math.exp(eps) * norm.cdf(-math.sqrt(2 * eps))


EPSILONS = [0.01, 0.1, 0.5, 0.9, 1.0, 2.0, 5.0, 10.0, 30.0]
DELTAS = [1e-10, 1e-5, 1e-2, 0.2, 0.45]


@pytest.mark.parametrize("eps", EPSILONS)
@pytest.mark.parametrize("delta", DELTAS)
def test_analytic_gaussian_satisfies_its_defining_condition(eps, delta):
    D = 0.7
    s = gaussian_sigma(eps, delta, D)
    assert s > 0
    assert abs(agm_condition(eps, delta, s, D) - delta) <= 1e-9 * delta
    # ... and is the smallest such sigma: slightly less noise violates (epsilon, delta)-DP.
    assert agm_condition(eps, delta, s * (1 - 1e-6), D) > delta


def test_both_branches_of_algorithm_1_are_exercised():
    pairs = [(e, d) for e in EPSILONS for d in DELTAS]
    assert any(d >= delta0(e) for e, d in pairs) and any(d < delta0(e) for e, d in pairs)


@given(eps=st.floats(0.01, 100.0), log10_delta=st.floats(-12.0, -0.05), D=st.floats(1e-3, 1e3))
@HYP
def test_analytic_gaussian_condition_property(eps, log10_delta, D):
    delta = 10.0 ** log10_delta
    s = gaussian_sigma(eps, delta, D)
    assert abs(agm_condition(eps, delta, s, D) - delta) <= 1e-9 * delta


@pytest.mark.parametrize("eps", [0.01, 0.1, 0.5, 0.9, 0.999])
@pytest.mark.parametrize("delta", [1e-10, 1e-5, 1e-2])
def test_analytic_gaussian_beats_the_classic_bound_below_epsilon_one(eps, delta):
    assert gaussian_sigma(eps, delta, 1.3) < classic_gaussian_sigma(eps, delta, 1.3)


def test_analytic_gaussian_scaling_and_monotonicity():
    assert gaussian_sigma(1.0, 1e-5, 0.0) == 0.0
    assert math.isclose(gaussian_sigma(2.0, 1e-5, 3.0), 3.0 * gaussian_sigma(2.0, 1e-5, 1.0), rel_tol=1e-12)
    s = [gaussian_sigma(e, 1e-5, 1.0) for e in (0.1, 0.5, 1.0, 2.0, 10.0, 100.0)]
    assert all(a > b for a, b in zip(s, s[1:]))
    s = [gaussian_sigma(1.0, d, 1.0) for d in (1e-12, 1e-6, 1e-3, 0.1, 0.5)]
    assert all(a > b for a, b in zip(s, s[1:]))


@pytest.mark.parametrize("args, name", [((0.0, 1e-5, 1.0), "epsilon"), ((-1.0, 1e-5, 1.0), "epsilon"),
                                        ((1.0, 0.0, 1.0), "delta"), ((1.0, 1.0, 1.0), "delta"),
                                        ((1.0, 1e-5, -1.0), "sensitivity"), ((math.inf, 1e-5, 1.0), "epsilon")])
def test_gaussian_sigma_rejects_bad_arguments(args, name):
    with pytest.raises(ParameterError, match=name):
        gaussian_sigma(*args)


def test_classic_bound_refuses_epsilon_at_least_one():
    assert math.isclose(classic_gaussian_sigma(0.5, 1e-5, 1.0), math.sqrt(2 * math.log(1.25e5)) / 0.5)
    with pytest.raises(ParameterError, match="epsilon"):
        classic_gaussian_sigma(1.0, 1e-5, 1.0)


# -------------------------------------------------------------------------------------------
# DP: the noisy message
# -------------------------------------------------------------------------------------------
def test_dp_message_adds_gaussian_noise_of_the_requested_std():
    rng = np.random.default_rng(7)
    z = rng.standard_normal((5000, 2)) * 0.03
    m = hardened(z.copy())
    sigma = 0.2
    out = dp_message(m, sigma, rng=8)
    noise = out.z - z
    n = noise.size                                  # 10,000 samples
    # The sample std of n Gaussian samples has standard error sigma / sqrt(2 n) (0.7 %):
    # 5 standard errors is 3.5 %. The mean has standard error sigma / sqrt(n): allow 5.
    assert abs(noise.std() / sigma - 1) < 5 / math.sqrt(2 * n)
    assert abs(noise.mean()) < 5 * sigma / math.sqrt(n)
    # Independent channels: sample correlation of n/2 pairs has standard error 1/sqrt(n/2).
    assert abs(np.corrcoef(noise[:, 0], noise[:, 1])[0, 1]) < 5 / math.sqrt(n / 2)
    # Every sample is noisy (also the padded tail), nothing else changes, the input is untouched.
    assert np.all(noise != 0)
    assert (out.mechanism, out.sample_rate, out.n_samples, out.count) == ("hardened", 200.0, m.n_samples, 1)
    np.testing.assert_array_equal(m.z, z)


def test_dp_message_is_reproducible_with_a_seed_and_zero_sigma_is_identity():
    z = np.random.default_rng(9).standard_normal((40, 2))
    m = hardened(z)
    np.testing.assert_array_equal(dp_message(m, 0.1, rng=1).z, dp_message(m, 0.1, rng=1).z)
    assert not np.array_equal(dp_message(m, 0.1, rng=1).z, dp_message(m, 0.1, rng=2).z)
    gen = np.random.default_rng(3)
    assert not np.array_equal(dp_message(m, 0.1, rng=gen).z, dp_message(m, 0.1, rng=gen).z)
    np.testing.assert_array_equal(dp_message(m, 0.0, rng=1).z, z)


def test_dp_message_rejects_bad_arguments():
    z = np.zeros((40, 2))
    with pytest.raises(ParameterError, match="sigma"):
        dp_message(hardened(z), -0.1)
    with pytest.raises(ParameterError, match="hardened"):
        dp_message(hardened(z, "fused"), 0.1)
    with pytest.raises(ParameterError, match="InversionMessage"):
        dp_message(z, 0.1)
    # A message with a non-finite z cannot be built (messages run the codec's checks), so it
    # can never reach the mechanism.
    with pytest.raises(MessageError, match="z must be finite"):
        hardened(np.full((40, 2), np.nan))


# -------------------------------------------------------------------------------------------
# Paillier
# -------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def keypair512():
    return paillier.generate_paillier_keypair(n_length=512)


def _check_byte_bounds(cost, n, key_bits):
    # A ciphertext is an integer modulo n^2 (2 * key_bits bits; a byte shorter with probability
    # about 1/256 per value) + 4 bytes of exponent.
    full = 2 * key_bits // 8 + 4
    assert full - 2 <= cost["bytes_per_value"] <= full
    assert cost["bytes_per_message"] == round(cost["bytes_per_value"] * n)


def test_paillier_round_trip_and_cost_small_message(keypair512):
    values = np.array([0.0, 1.0, -1.0, 3.5e-3, -2.25e2, 1e-9, 123.456789012345])
    cost = paillier_cost(values, key_bits=512, keypair=keypair512, packing=False)
    assert cost["n_values"] == 7 and cost["extrapolated_from"] is None
    assert math.isnan(cost["keygen_ms"])
    assert cost["ms_per_value"] > 0 and cost["decrypt_ms_per_value"] > 0
    assert math.isclose(cost["ms_per_message"], 7 * cost["ms_per_value"])
    assert cost["precision"] == pytest.approx(1e-13 * 225.0)
    _check_byte_bounds(cost, 7, 512)
    # The same encoding by hand: decrypt(encrypt(x)) == x to 1e-12 of full scale.
    pub, priv = keypair512
    back = np.array([priv.decrypt(pub.encrypt(float(v), precision=cost["precision"])) for v in values])
    assert np.max(np.abs(back - values)) <= 1e-12 * 225.0


def test_paillier_extrapolates_from_a_sample(keypair512):
    z = np.random.default_rng(10).standard_normal((100, 2)) * 0.05
    m = hardened(z)
    cost = paillier_cost(m, key_bits=512, sample=8, rng=0, keypair=keypair512, packing=False)
    assert cost["n_values"] == 200 and cost["extrapolated_from"] == 8
    assert math.isclose(cost["ms_per_message"], 200 * cost["ms_per_value"])
    _check_byte_bounds(cost, 200, 512)


def test_paillier_generates_and_times_its_own_key():
    cost = paillier_cost([0.5, -0.25, 1e-3], key_bits=1024, packing=False)
    assert cost["keygen_ms"] > 0 and cost["key_bits"] == 1024
    _check_byte_bounds(cost, 3, 1024)


def test_paillier_round_trip_check_can_fail(keypair512, monkeypatch):
    pub, priv = keypair512
    honest = priv.decrypt
    monkeypatch.setattr(priv, "decrypt", lambda c: honest(c) + 1e-6)
    with pytest.raises(RuntimeError, match="round trip"):
        paillier_cost([1.0, 2.0], key_bits=512, keypair=keypair512, packing=False)


def test_paillier_rejects_bad_arguments(keypair512):
    with pytest.raises(ParameterError, match="key_bits"):
        paillier_cost([1.0], key_bits=2048, keypair=keypair512)        # 512-bit keys
    with pytest.raises(ParameterError, match="keypair"):
        paillier_cost([1.0], key_bits=512, keypair=("pub", "priv"))
    other = paillier.generate_paillier_keypair(n_length=512)
    with pytest.raises(ParameterError, match="keypair"):
        paillier_cost([1.0], key_bits=512, keypair=(keypair512[0], other[1]))
    with pytest.raises(ParameterError, match="values"):
        paillier_cost([], key_bits=512, keypair=keypair512)
    with pytest.raises(ParameterError, match="values"):
        paillier_cost([1.0, np.inf], key_bits=512, keypair=keypair512)
    with pytest.raises(ParameterError, match="sample"):
        paillier_cost([1.0], key_bits=512, sample=0, keypair=keypair512)
    with pytest.raises(ParameterError, match="precision"):
        paillier_cost([1.0], key_bits=512, keypair=keypair512, precision=0.0)


def test_packed_slot_layout_of_the_deployed_key():
    # 1e-13 of full scale needs 46 bits; 16 summands add 4; a 56-bit slot, 36 slots in 2047 bits.
    assert slot_layout(1.0, 1e-13, 2048, 16) == (46, 56, 36)
    assert slot_layout(1.0, 1e-13, 2048, 1) == (46, 48, 42)


def test_paillier_packed_round_trip_and_cost(keypair512):
    x = np.random.default_rng(11).standard_normal(200) * 0.05
    cost = paillier_cost(x, key_bits=512, keypair=keypair512, sample=3, rng=0)
    v, w, slots = slot_layout(float(np.max(np.abs(x))), cost["precision"], 512, 16)
    assert cost["packing"] and cost["values_per_ciphertext"] == slots == 511 // w
    assert cost["n_ciphertexts"] == math.ceil(200 / slots) and cost["extrapolated_from"] == 3
    # Ciphertexts are integers mod n^2, sent at fixed width (no exponent: the precision is public).
    assert cost["bytes_per_message"] == cost["n_ciphertexts"] * 128
    assert cost["ms_per_message"] > 0 and cost["offline_ms_per_message"] > 0 and cost["decrypt_ms_per_message"] > 0
    assert cost["gmpy2"]


def test_packed_ciphertexts_add_homomorphically_within_the_headroom(keypair512):
    pub, priv = keypair512
    gen = np.random.default_rng(12)
    xs = [gen.uniform(-1.0, 1.0, 50) for _ in range(16)]
    prec = 1e-13
    v, w, slots = slot_layout(1.0, prec, 512, 16)
    n2 = pub.nsquare
    total = 1
    for x in xs:
        plain = pack(x, prec, v, w, slots)
        for_sum = encrypt_packed(pub, plain, precompute_rn(pub, len(plain)))
        total = for_sum if total == 1 else [a * b % n2 for a, b in zip(total, for_sum)]
    back = unpack([priv.raw_decrypt(int(c)) for c in total], 50, prec, v, w, slots, n_summands=16)
    assert np.max(np.abs(back - np.sum(xs, axis=0))) <= 16 * prec


def test_paillier_packed_round_trip_check_can_fail(keypair512, monkeypatch):
    pub, priv = keypair512
    honest = priv.raw_decrypt
    monkeypatch.setattr(priv, "raw_decrypt", lambda c: honest(c) + 1000)
    with pytest.raises(RuntimeError, match="round trip"):
        paillier_cost([1.0, 2.0], key_bits=512, keypair=keypair512)


def test_paillier_packing_arguments(keypair512):
    with pytest.raises(ParameterError, match="packing"):
        paillier_cost([1.0], key_bits=512, keypair=keypair512, packing="yes")
    with pytest.raises(ParameterError, match="n_summands"):
        paillier_cost([1.0], key_bits=512, keypair=keypair512, n_summands=0)


# -------------------------------------------------------------------------------------------
# AEAD channel
# -------------------------------------------------------------------------------------------
KEY = bytes(range(32))
BLOB = seal(KEY, b"road input estimate z", associated_data=b"segment 7")


def test_new_key_is_32_random_bytes():
    a, b = new_key(), new_key()
    assert isinstance(a, bytes) and len(a) == 32 and a != b


@given(data=st.binary(max_size=2000), ad=st.binary(max_size=64))
@HYP
def test_seal_open_round_trip(data, ad):
    blob = seal(KEY, data, associated_data=ad)
    assert len(blob) == len(data) + AEAD_OVERHEAD_BYTES == len(data) + 28
    assert open_sealed(KEY, blob, associated_data=ad) == data


def test_nonce_is_fresh_and_bytes_like_inputs_are_accepted():
    data = b"\x00" * 64
    a, b = seal(KEY, data), seal(KEY, data)
    assert a[:12] != b[:12] and a != b
    assert open_sealed(bytearray(KEY), memoryview(a)) == data
    assert open_sealed(KEY, seal(KEY, bytearray(data), associated_data=memoryview(b"x")),
                       associated_data=b"x") == data


@given(pos=st.integers(0, len(BLOB) - 1), mask=st.integers(1, 255))
@HYP
def test_any_single_byte_flip_is_refused(pos, mask):
    bad = bytearray(BLOB)
    bad[pos] ^= mask
    with pytest.raises(MessageError):
        open_sealed(KEY, bytes(bad), associated_data=b"segment 7")


@given(cut=st.integers(0, len(BLOB) - 1))
@HYP
def test_any_truncation_is_refused(cut):
    with pytest.raises(MessageError):
        open_sealed(KEY, BLOB[:cut], associated_data=b"segment 7")


def test_wrong_key_extension_and_wrong_associated_data_are_refused():
    with pytest.raises(MessageError):
        open_sealed(new_key(), BLOB, associated_data=b"segment 7")
    with pytest.raises(MessageError):
        open_sealed(KEY, BLOB + b"\x00", associated_data=b"segment 7")
    with pytest.raises(MessageError):
        open_sealed(KEY, BLOB, associated_data=b"segment 8")
    with pytest.raises(MessageError):
        open_sealed(KEY, BLOB)


@pytest.mark.parametrize("blob", [None, "text", 42, [1, 2, 3], np.zeros(40, np.uint8)])
def test_non_bytes_blob_is_a_message_error(blob):
    with pytest.raises(MessageError):
        open_sealed(KEY, blob)


def test_bad_keys_and_plaintexts_are_parameter_errors():
    for key in (b"short", bytes(33), "k" * 32, None):
        with pytest.raises(ParameterError, match="key"):
            seal(key, b"data")
        with pytest.raises(ParameterError, match="key"):
            open_sealed(key, BLOB)
    with pytest.raises(ParameterError, match="data"):
        seal(KEY, "text")
    with pytest.raises(ParameterError, match="associated_data"):
        seal(KEY, b"data", associated_data="ad")


def test_aead_cost():
    cost = aead_cost(b"\x01" * 1000, repeats=5)
    assert cost["bytes_per_message"] == 1028 and cost["overhead_bytes"] == 28
    assert 0 < cost["ms_per_message"] < 1000 and 0 < cost["open_ms_per_message"] < 1000
    m = hardened(np.random.default_rng(11).standard_normal((48, 2)))
    cost = aead_cost(m, repeats=3)
    assert cost["bytes_per_message"] == inversion_nbytes(48) + 28 == len(encode(m)) + 28
    with pytest.raises(ParameterError, match="repeats"):
        aead_cost(b"x", repeats=0)
    with pytest.raises(ParameterError, match="data"):
        aead_cost("text")
