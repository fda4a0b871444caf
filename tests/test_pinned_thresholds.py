"""Thresholds that mutation testing found unpinned (issue 23, section 4).

The receiver guard's stated rule (:mod:`roadcollab.collaboration.guard`): per band ``b`` the
statistic is ``r_b = sum_b |z_msg - z_own|^2 / sum_b v`` with
``v = 2 W^2 tr(E[(A - I) S (A - I)^H] + N sigma^2 P_hat^-1 P_hat^-H)``, ``A = P_hat^-1 P`` over
the receiver's posterior plants, and a band is refused iff ``r_b > 10``. The tests below compute
``v`` independently (dense ``numpy.linalg.inv``, an explicit loop over draws), build messages whose
band statistic is a chosen multiple of the threshold, and check the decision on both sides of it:
a threshold of 11, 20 or 100, or a factor 2.2 (or 1.8) instead of 2, flips one of them.

The anomaly match's stated rule (:func:`roadcollab.detection.scoring.match_detections`): centers
*within* ``tolerance`` m match, so a distance of exactly ``tolerance`` is a match.
"""

import numpy as np
import pytest

import roadcollab as rc
from roadcollab.collaboration.guard import ReceiverGuard
from roadcollab.detection.scoring import match_detections
from roadcollab.detection.detector import Detection
from roadcollab.experiments.pipeline import PipelineCache, record_run
from roadcollab.experiments.seeds import SeedPlan, run_stream
from roadcollab.models.road import Anomaly
from roadcollab.wire.message import InversionMessage

SMALL = rc.ExperimentConfig(n_vehicles=2, n_runs=1, segment_length=120.0)
THRESHOLD = 10.0          # the module docstring's a-priori threshold


@pytest.fixture(scope="module")
def receiver():
    cfg = SMALL
    pipe = PipelineCache().pipeline(cfg, 0)
    ss = SeedPlan(0).runs(1)[0]
    _, _, Ys = record_run(pipe, run_stream(ss, "road"), run_stream(ss, "noise"), cfg.sensor_noise_std)
    est = pipe.estimators[1]
    guard = ReceiverGuard(est, pipe.road_moment, cfg.sensor_noise_std)
    return cfg, pipe, est, guard, Ys[1]


def _expected_v(est, S, noise_std):
    """``v`` per active bin from the guard's stated closed form, computed independently."""
    g = est.grid
    act = g.active
    P_hat = est.P_f[act]
    draws = est.posterior_responses                      # (n_models, K_active, 2, 2) plausible true P
    v = np.zeros(P_hat.shape[0])
    for k in range(P_hat.shape[0]):
        Pinv = np.linalg.inv(P_hat[k])
        param = np.zeros((2, 2), complex)
        for P in draws[:, k]:
            A = Pinv @ P - np.eye(2)
            param += A @ S[k] @ A.conj().T
        param /= draws.shape[0]
        noise = g.n_samples * noise_std ** 2 * Pinv @ Pinv.conj().T
        v[k] = 2.0 * g.reg_weight[act][k] ** 2 * np.real(np.trace(param + noise))
    return v


def _message_with_band_statistic(est, guard, Y, v, band, ratio):
    """An inversion message equal to the receiver's own ``z`` except in ``band``, where
    ``sum |d|^2 = ratio * sum v`` (``v`` from the closed form)."""
    g = est.grid
    act_idx = np.flatnonzero(g.active)
    Z = est.invert(Y).copy()
    bins = guard.bands[band]
    rng = np.random.default_rng(5)
    U = rng.standard_normal((bins.size, 2)) + 1j * rng.standard_normal((bins.size, 2))
    U *= np.sqrt(ratio * v[bins].sum() / np.sum(np.abs(U) ** 2))
    Z[act_idx[bins]] += U
    z = g.irfft(Z)
    return InversionMessage(mechanism="hardened", sample_rate=g.sample_rate, n_samples=g.n_samples, z=z)


@pytest.fixture(scope="module")
def guarded(receiver):
    cfg, pipe, est, guard, Y = receiver
    v = _expected_v(est, pipe.road_moment, cfg.sensor_noise_std)
    return est, guard, Y, v


def test_closed_form_band_expectation_matches_the_guard(guarded):
    est, guard, Y, v = guarded
    np.testing.assert_allclose(guard.expected, v, rtol=1e-9)
    assert len(guard.bands) >= 3


def test_honest_copy_of_own_inversion_has_zero_statistic(guarded):
    est, guard, Y, v = guarded
    g = est.grid
    msg = InversionMessage(mechanism="hardened", sample_rate=g.sample_rate, n_samples=g.n_samples,
                           z=g.irfft(est.invert(Y)))
    _, report = guard.check(msg, Y)
    assert not report.refused
    assert max(report.statistics) < 1e-12


@pytest.mark.parametrize("ratio, refused", [(0.95, False), (1.05, True), (0.5, False), (1.5, True)])
def test_band_refused_iff_statistic_exceeds_ten(guarded, ratio, refused):
    est, guard, Y, v = guarded
    band = 1
    msg = _message_with_band_statistic(est, guard, Y, v, band, ratio * THRESHOLD)
    _, report = guard.check(msg, Y)
    assert report.statistics[band] == pytest.approx(ratio * THRESHOLD, rel=1e-6)
    others = [r for i, r in enumerate(report.statistics) if i != band]
    assert max(others) < 1e-9
    assert not report.whole_message_refused
    assert (band in report.refused_bands) is refused
    assert report.refused_bands == ((band,) if refused else ())
    if refused:
        assert report.reasons == (f"band {band} ({guard.band_edges_hz[band][0]:.3g}-"
                                  f"{guard.band_edges_hz[band][1]:.3g} Hz): r = {ratio * THRESHOLD:.3g} > 10",)


def test_guarded_z_keeps_accepted_band_and_zeroes_refused_band(guarded):
    est, guard, Y, v = guarded
    band = 1
    bins = guard.bands[band]
    z_own = est.invert(Y)[est.grid.active]
    for ratio, keep in ((0.95, True), (1.05, False)):
        msg = _message_with_band_statistic(est, guard, Y, v, band, ratio * THRESHOLD)
        z, _ = guard.check(msg, Y)
        sent = est.received_z(msg)
        np.testing.assert_array_equal(z[bins], sent[bins] if keep else 0.0)
        others = np.setdiff1d(np.arange(z_own.shape[0]), bins)
        np.testing.assert_array_equal(z[others], sent[others])


def _one_pothole_at_10m():
    return [Anomaly(9.75, "left", "pothole", 0.05, 0.5)]          # center 9.75 + 0.5 / 2 = 10.0 m exactly


def _det(x):
    return Detection(position=x, side="left", kind="pothole", depth=0.05, confidence=0.9)


@pytest.mark.parametrize("position", [11.0, 9.0])
def test_match_at_exactly_the_tolerance_counts(position):
    # |11.0 - 10.0| and |9.0 - 10.0| are exactly 1.0 in binary floating point.
    assert abs(position - 10.0) == 1.0
    m = match_detections([_det(position)], _one_pothole_at_10m(), tolerance=1.0)
    assert (m.n_matched, m.n_detected, m.n_true) == (1, 1, 1)
    assert m.position_errors == (1.0,)


def test_match_tolerance_other_than_one_is_inclusive_too():
    # 0.25 and 2.5 are exact binary fractions: the boundary is hit exactly.
    assert match_detections([_det(10.25)], _one_pothole_at_10m(), tolerance=0.25).n_matched == 1
    assert match_detections([_det(12.5)], _one_pothole_at_10m(), tolerance=2.5).n_matched == 1
    assert match_detections([_det(np.nextafter(12.5, 13.0))], _one_pothole_at_10m(), tolerance=2.5).n_matched == 0
