"""Tests for the survivors of the fourth mutation pass (docs/mutation.md): the receiver guard's ``check`` and
``_bad_bins``, ``match_detections``, ``_assign`` and ``detect_anomalies``, from stated rules and boundary values."""

import dataclasses
import math
import re
import warnings

import numpy as np
import pytest

import roadcollab as rc
from roadcollab.collaboration.guard import ReceiverGuard
from roadcollab.collaboration.relay import Exchange, Relay
from roadcollab.detection.detector import MAX_ROAD_VELOCITY, Detection
from roadcollab.detection.scoring import match_detections
from roadcollab.errors import ParameterError
from roadcollab.experiments.pipeline import PipelineCache, record_run
from roadcollab.experiments.seeds import SeedPlan, run_stream
from roadcollab.lti.batch2x2 import condition_2x2
from roadcollab.lti.realisation import StateSpaceData
from roadcollab.models.road import Anomaly
from roadcollab.wire.message import InversionMessage

SMALL = rc.ExperimentConfig(n_vehicles=2, n_runs=1, segment_length=120.0)
FS, SPEED = 200.0, 15.0
DS = SPEED / FS


@pytest.fixture(scope="module")
def honest():
    """Vehicle 1's guard, its record spectrum and vehicle 0's honest exchange message."""
    cfg = SMALL
    pipe = PipelineCache().pipeline(cfg, 0)
    ss = SeedPlan(0).runs(1)[0]
    _, ys, Ys = record_run(pipe, run_stream(ss, "road"), run_stream(ss, "noise"), cfg.sensor_noise_std)
    steps = Relay(pipe.estimators, Exchange("none", cfg.obfuscation), rng=3, unguarded=True).run(ys, spectra=Ys)
    est = pipe.estimators[1]
    return pipe, est, Ys[1], steps[0].message


def _guard(pipe, est, **kw):
    return ReceiverGuard(est, pipe.road_moment, SMALL.sensor_noise_std, **kw)


def test_guard_names_what_is_not_a_message_and_what_does_not_fit(honest):
    pipe, est, Y, _ = honest
    guard = _guard(pipe, est)
    _, rep = guard.check("junk", Y)
    assert rep.refused and rep.reasons == ("not a message: str",)
    g = est.grid
    short = InversionMessage(mechanism="hardened", sample_rate=g.sample_rate, n_samples=g.n_samples - 1,
                             z=np.zeros((g.n_samples - 1, 2)))
    _, rep = guard.check(short, Y)
    assert rep.refused and rep.reasons[0].startswith("does not fit the receiver: ")


def test_guard_refuses_a_singular_T_on_every_bin_without_floating_point_errors(honest):
    pipe, est, Y, msg = honest
    T = msg.T
    singular = StateSpaceData(T.A, np.zeros_like(T.B), np.zeros_like(T.C), np.ones((2, 2)), T.dt)   # T(z) = [[1,1],[1,1]]
    forged = dataclasses.replace(msg, T=singular)
    with np.errstate(all="raise"):                     # the guard must silence its own inf/nan arithmetic
        z, rep = _guard(pipe, est).check(forged, Y)
    assert rep.refused and rep.reasons == ("T ill-conditioned (cond > 1e+08) or not finite on every bin",)
    assert not z.any()


def test_guard_max_condition_is_inclusive(honest):
    pipe, est, Y, msg = honest
    T = est.response_cache.response(msg.T, est.grid.omega_dt[est.grid.active])
    cond = condition_2x2(T)
    worst = float(cond.max())                          # a T exactly at max_condition is accepted
    _, rep = _guard(pipe, est, max_condition=worst).check(msg, Y)
    assert not any("ill-conditioned" in r for r in rep.reasons), rep.reasons
    _, rep = _guard(pipe, est, max_condition=float(np.nextafter(worst, 0.0))).check(msg, Y)
    assert any("ill-conditioned" in r for r in rep.reasons)


# -- match_detections and _assign ---------------------------------------------------------------------------

def _det(x, side="left", kind="pothole", depth=0.05):
    return Detection(position=x, side=side, kind=kind, depth=depth, confidence=0.9)


def _truth(center, side="left"):
    return Anomaly(center - 0.25, side, "pothole", 0.05, 0.5)       # 0.5 m long: center = start + 0.25


def test_region_edges_are_inclusive_for_truth_and_false_positives():
    truth = [_truth(10.0), _truth(20.0)]
    m = match_detections([], truth, region=(10.0, 20.0))
    assert m.n_true == 2                                # true centers exactly at both edges count
    m = match_detections([_det(10.0), _det(20.0)], [], region=(10.0, 20.0))
    assert m.n_detected == 2                            # unmatched detections exactly at both edges count


def test_no_matched_pair_gives_nan_agreement_without_a_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")                  # np.mean([]) would warn "Mean of empty slice"
        m = match_detections([_det(50.0)], [_truth(10.0)])
    assert m.n_matched == 0 and math.isnan(m.kind_accuracy) and math.isnan(m.side_accuracy)


def test_assign_prefers_a_feasible_pair_over_an_infeasible_one_at_a_small_tolerance():
    # One detection; truth 0 is 0.3 m away (feasible at tolerance 0.5), truth 1 on the other track (infeasible).
    m = match_detections([_det(10.3)], [_truth(10.0), _truth(10.3, side="right")], tolerance=0.5)
    assert m.n_matched == 1 and m.pairs == ((0, 0),)


def test_assign_maximises_the_number_of_pairs_before_the_distance():
    # d0-t0 and d1-t1 are 0.9 m apart (sum 1.8); d0-t1 is 0.1 m but d1-t0 is 1.9 m (infeasible): the most
    # pairs is two, so (d0, t0), (d1, t1) although d0-t1 alone is closer than 1.8 m.
    dets = [_det(10.0), _det(11.0)]
    truth = [_truth(9.1), _truth(10.1)]
    m = match_detections(dets, truth, tolerance=1.0)
    assert m.n_matched == 2 and set(m.pairs) == {(0, 0), (1, 1)}


# -- detect_anomalies -------------------------------------------------------------------------------------------

def _road(n=4000, x0=0.0):
    x = x0 + np.arange(n) * DS
    return x, np.zeros((n, 2))


def test_detector_names_a_wrong_spec_type():
    x, w = _road()
    with pytest.raises(ParameterError, match="spec must be a DetectorSpec, got str"):
        rc.detect_anomalies(w, positions=x, speed=SPEED, sample_rate=FS, spec="default")


def test_detector_speed_limit_is_inclusive_and_its_error_names_the_value():
    x, w = _road()
    w[100, 0] = MAX_ROAD_VELOCITY                        # exactly the limit: accepted
    rc.detect_anomalies(w, positions=x, speed=SPEED, sample_rate=FS)
    w[100, 0] = 2 * MAX_ROAD_VELOCITY
    with pytest.raises(ParameterError, match=r"w_hat must be a road velocity below 1e\+06 m/s in magnitude, "
                                             r"got 2e\+06 m/s"):
        rc.detect_anomalies(w, positions=x, speed=SPEED, sample_rate=FS)


def test_detector_length_boundary_is_the_one_its_error_states():
    x, w = _road(5)
    with pytest.raises(ParameterError, match="longest template") as err:
        rc.detect_anomalies(w, positions=x, speed=SPEED, sample_rate=FS)
    need = int(re.search(r"need >= (\d+) samples", str(err.value)).group(1))
    x, w = _road(need)
    rc.detect_anomalies(w, positions=x, speed=SPEED, sample_rate=FS)      # exactly the stated minimum: accepted
    x, w = _road(need - 1)
    with pytest.raises(ParameterError, match=f"need >= {need} samples"):
        rc.detect_anomalies(w, positions=x, speed=SPEED, sample_rate=FS)


@pytest.mark.parametrize("n, message", [(1, "w_hat must have at least 2 samples, got 1"),
                                        (2, "w_hat must cover more than the longest template")])
def test_detector_short_signal_errors(n, message):
    x, w = _road(n)
    with pytest.raises(ParameterError, match=message):
        rc.detect_anomalies(w, positions=x, speed=SPEED, sample_rate=FS)


def test_detector_spacing_tolerance_is_relative_to_the_step_and_to_the_position():
    # Near 0 the tolerance is 1e-6 ds (7.5e-8 m): a 1e-6 m step error is refused.
    x, w = _road()
    x[2000:] += 1e-6
    with pytest.raises(ParameterError, match="positions must be uniformly spaced"):
        rc.detect_anomalies(w, positions=x, speed=SPEED, sample_rate=FS)
    # At 1e6 m it is dominated by 1e-9 |x| = 1e-3 m (float rounding of large positions): 1e-5 m is accepted.
    x, w = _road(x0=1e6)
    x[2000:] += 1e-5
    rc.detect_anomalies(w, positions=x, speed=SPEED, sample_rate=FS)
