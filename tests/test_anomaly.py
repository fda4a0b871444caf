"""Tests of roadcollab.detection.detector (detector, scoring) and roadcollab.experiments.anomalies.study."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.ndimage import uniform_filter1d

from roadcollab.detection.detector import Detection, DetectorSpec, detect_anomalies
from roadcollab.detection.scoring import match_detections
from roadcollab.experiments.anomalies.config import ESTIMATORS, AnomalyStudyConfig
from roadcollab.experiments.anomalies.study import run_anomaly_study
from roadcollab.errors import ParameterError
from roadcollab.experiments.config import ExperimentConfig
from roadcollab.models.anomaly import Anomaly
from roadcollab.models.profile import RoadProfile
from roadcollab.models.road import RoadSpec, generate_road
from roadcollab.estimation.grid import SegmentGrid

SPEED, FS = 15.0, 200.0


def velocity_of(anomalies, *, length=80.0, enveloping=0.25, band_limit=True):
    """Band-limited road velocity (N, 2) and sample positions of a hand-made profile: the
    anomalies only (no roughness), tyre enveloping as in the road model, 15 m/s at 200 Hz."""
    x = np.arange(0.0, length + 1e-9, 0.05)
    z = np.zeros((x.size, 2))
    for a in anomalies:
        for c in a.tracks:
            z[:, c] += a.elevation(x)
    size = int(round(enveloping / 0.05)) | 1
    z = uniform_filter1d(z, size, axis=0, mode="nearest")
    road = RoadProfile(x, z, tuple(anomalies)).sample(SPEED, FS, duration=(length - 1.0) / SPEED)
    w = road.velocity
    if band_limit:
        w = SegmentGrid(w.shape[0], FS).band_limit(w)
    return w, road.positions[:-1]


def detect(w, positions, **kw):
    return detect_anomalies(w, positions=positions, speed=SPEED, sample_rate=FS, **kw)


# --- detector on clean signals -----------------------------------------------------------------

def test_clean_pothole_and_bump_found_with_kind_side_center_depth():
    pothole = Anomaly(30.0, "left", "pothole", 0.05, 0.5)
    bump = Anomaly(50.0, "right", "bump", 0.04, 1.5)
    w, pos = velocity_of([pothole, bump])
    dets = detect(w, pos)
    assert len(dets) == 2, dets
    for d, a in zip(dets, (pothole, bump)):
        assert (d.kind, d.side) == (a.kind, a.side)
        assert abs(d.position - a.center) <= 0.25
        assert abs(d.depth - a.depth) <= 0.2 * a.depth
        assert d.confidence > 0.99


@pytest.mark.parametrize("length", [0.2, 0.35, 0.9])
def test_clean_pothole_lengths_and_unbandlimited_input(length):
    a = Anomaly(40.0, "right", "pothole", 0.03, length)
    for band in (True, False):
        dets = detect(*velocity_of([a], band_limit=band))
        assert [(d.kind, d.side) for d in dets] == [("pothole", "right")]
        assert abs(dets[0].position - a.center) <= 0.25
        # Short potholes are narrower than the tyre: their depth is only known to ~30 %.
        assert abs(dets[0].depth - a.depth) <= (0.2 if length >= 0.3 else 0.35) * a.depth


def test_no_detections_on_zero_or_low_noise_signal():
    n = 5000
    pos = np.arange(n) * SPEED / FS
    assert detect(np.zeros((n, 2)), pos) == []
    rng = np.random.default_rng(7)
    # 1 mm/s white road velocity: elevation wiggles of ~0.1 mm, far below min_depth.
    assert detect(1e-3 * rng.standard_normal((n, 2)), pos) == []
    # 0.05 m/s white road velocity (a smooth road; class C is ~0.4 m/s per sample): its
    # elevation features are a few mm, below min_depth, whatever their SNR.
    assert detect(0.05 * rng.standard_normal((n, 2)), pos) == []
    assert detect(0.05 * rng.standard_normal((n, 2)), pos, spec=DetectorSpec(min_depth=0.0))   # SNR alone


def test_left_and_right_detections_merge_into_both():
    both = Anomaly(30.0, "both", "pothole", 0.04, 0.4)
    left = Anomaly(45.0, "left", "bump", 0.05, 1.0)
    right = Anomaly(60.0, "right", "pothole", 0.05, 0.6)
    dets = detect(*velocity_of([both, left, right]))
    assert [(d.side, d.kind) for d in dets] == [("both", "pothole"), ("left", "bump"), ("right", "pothole")]
    assert abs(dets[0].position - both.center) <= 0.25
    assert abs(dets[0].depth - both.depth) <= 0.2 * both.depth
    # A left and a right pothole 0.3 m apart are merged; 1 m apart they are not.
    near = [Anomaly(30.0, "left", "pothole", 0.04, 0.4), Anomaly(30.3, "right", "pothole", 0.04, 0.4)]
    assert [d.side for d in detect(*velocity_of(near))] == ["both"]
    far = [Anomaly(30.0, "left", "pothole", 0.04, 0.4), Anomaly(31.0, "right", "pothole", 0.04, 0.4)]
    assert [d.side for d in detect(*velocity_of(far))] == ["left", "right"]
    # A pothole and a bump side by side are two anomalies, not one "both".
    mixed = [Anomaly(30.0, "left", "pothole", 0.04, 0.4), Anomaly(29.5, "right", "bump", 0.04, 1.2)]
    assert sorted((d.side, d.kind) for d in detect(*velocity_of(mixed))) == [("left", "pothole"), ("right", "bump")]


def test_weak_copy_on_the_other_track_is_crosstalk():
    w, pos = velocity_of([Anomaly(30.0, "left", "pothole", 0.06, 0.5)])
    w = w.copy()
    w[:, 1] = 0.25 * w[:, 0]         # 25 % leakage (1.5 cm, above min_depth) into the right estimate
    dets = detect(w, pos)
    assert [(d.side, d.kind) for d in dets] == [("left", "pothole")]
    # Without cross-talk rejection the leakage is reported as a "both" anomaly.
    assert [d.side for d in detect(w, pos, spec=DetectorSpec(crosstalk_ratio=0.0))] == ["both"]
    # Leakage of the opposite sign looks like a raise on the right: still cross-talk.
    w[:, 1] = -0.2 * w[:, 0]
    assert [(d.side, d.kind) for d in detect(w, pos)] == [("left", "pothole")]
    assert sorted(d.side for d in detect(w, pos, spec=DetectorSpec(crosstalk_ratio=0.0))) == ["left", "right"]


def test_threshold_and_min_depth_govern_reporting():
    w, pos = velocity_of([Anomaly(30.0, "left", "bump", 0.03, 1.0)])
    assert len(detect(w, pos)) == 1
    assert detect(w, pos, spec=DetectorSpec(min_depth=0.04)) == []
    # Clean signal: sigma is the noise floor, so the SNR is 1 / noise_floor times a constant:
    # for a raised cosine sum(h^2) ~ ds pi^2 / (2 L), so snr ~ 0.03 / (0.45 noise_floor) ~ 67.
    assert len(detect(w, pos, spec=DetectorSpec(noise_floor=1e-3, snr_threshold=40.0))) == 1
    assert detect(w, pos, spec=DetectorSpec(noise_floor=1e-3, snr_threshold=100.0)) == []
    assert len(detect(w, pos, spec=DetectorSpec(noise_floor=1e-4, snr_threshold=100.0))) == 1


def test_detects_anomalies_on_a_seeded_rough_road_truth():
    """Band-limited true velocity of a class B road with default anomalies (2.5-10 cm): all
    found, nothing else (regression on a fixed seed)."""
    spec = RoadSpec(length=331.0, iso_class="B", anomaly_margin=15.0)
    road = generate_road(spec, rng=11).sample(SPEED, FS, duration=330.0 / SPEED)
    w = SegmentGrid(road.velocity.shape[0], FS).band_limit(road.velocity)
    m = match_detections(detect(w, road.positions[:-1]), road.anomalies, region=(15.0, 315.0))
    assert m.n_true >= 4
    assert m.recall == 1.0 and m.precision == 1.0
    assert m.median_position_error_m <= 0.2
    assert m.kind_accuracy == 1.0


# --- scoring -----------------------------------------------------------------------------------

def _det(pos, side="left", kind="pothole", depth=0.05, confidence=0.9):
    return Detection(pos, side, kind, depth, confidence)


TRUTH = (Anomaly(9.5, "left", "pothole", 0.05, 1.0),     # center 10
         Anomaly(19.0, "right", "bump", 0.04, 2.0),      # center 20
         Anomaly(29.75, "both", "pothole", 0.03, 0.5))   # center 30


def test_match_oracle_one_false_positive_one_miss():
    dets = [_det(10.0, "left"), _det(20.0, "right", "bump"), _det(50.0, "right")]
    m = match_detections(dets, TRUTH)
    assert (m.n_true, m.n_detected, m.n_matched) == (3, 3, 2)
    assert m.precision == pytest.approx(2 / 3) and m.recall == pytest.approx(2 / 3)
    assert m.f1 == pytest.approx(2 / 3)
    assert m.median_position_error_m == pytest.approx(0.0, abs=1e-12)
    assert m.kind_accuracy == 1.0 and m.side_accuracy == 1.0
    assert m.median_depth_rel_error == pytest.approx(0.125)   # median of 0 (pothole), 0.25 (bump)


def test_match_exact_sides_kinds_and_tolerance():
    exact = [_det(10.0, "left"), _det(20.0, "right", "bump"), _det(30.0, "both")]
    m = match_detections(exact, TRUTH)
    assert (m.precision, m.recall, m.f1) == (1.0, 1.0, 1.0)
    # A "both" truth is matched by a one-sided detection (side_accuracy records it); a "both"
    # detection matches a one-sided truth; left never matches right.
    m = match_detections([_det(30.2, "right"), _det(10.3, "both")], TRUTH)
    assert m.n_matched == 2 and m.side_accuracy == 0.0
    assert sorted(m.position_errors) == pytest.approx([0.2, 0.3])
    assert match_detections([_det(20.0, "left", "bump")], TRUTH).n_matched == 0
    # Kind need not agree for a match; it is reported separately.
    m = match_detections([_det(10.0, "left", "bump"), _det(20.0, "right", "bump")], TRUTH)
    assert m.n_matched == 2 and m.kind_accuracy == 0.5
    # Tolerance on the center distance.
    assert match_detections([_det(11.2, "left")], TRUTH).n_matched == 0
    assert match_detections([_det(11.2, "left")], TRUTH, tolerance=1.5).n_matched == 1


def test_match_is_optimal_not_greedy():
    truth = [Anomaly(9.5, "left", "pothole", 0.05, 1.0), Anomaly(10.5, "left", "pothole", 0.05, 1.0)]  # 10, 11
    # Greedy closest-first would pair 10.6 with 11 (0.4) and leave 11.8 unmatched (1.8 from 10).
    m = match_detections([_det(10.6), _det(11.8)], truth, tolerance=1.0)
    assert m.n_matched == 2
    assert sorted(m.position_errors) == pytest.approx([0.6, 0.8])


def test_match_region_filtering():
    dets = [_det(10.0, "left"), _det(20.0, "right", "bump"), _det(50.0, "right"), _det(29.9, "both")]
    # Region [15, 40]: truths at 20 and 30 count; the detection at 10 matches an uncounted truth
    # (ignored), the one at 50 is outside and unmatched (ignored).
    m = match_detections(dets, TRUTH, region=(15.0, 40.0))
    assert (m.n_true, m.n_detected, m.n_matched) == (2, 2, 2)
    assert m.precision == 1.0 and m.recall == 1.0
    # Region [0, 60] counts everything: the detection at 50 is a false positive.
    m = match_detections(dets, TRUTH, region=(0.0, 60.0))
    assert (m.n_true, m.n_detected, m.n_matched) == (3, 4, 3)
    assert m.precision == pytest.approx(0.75)
    # A truth just inside the edge matched by a detection just outside it counts as found.
    m = match_detections([_det(14.6)], [Anomaly(15.0, "left", "pothole", 0.05, 0.2)], region=(15.0, 40.0))
    assert (m.n_true, m.n_detected, m.n_matched) == (1, 1, 1)


def test_match_empty_conventions():
    m = match_detections([], [])
    assert (m.precision, m.recall, m.n_true, m.n_detected) == (1.0, 1.0, 0, 0)
    m = match_detections([], TRUTH)
    assert (m.precision, m.recall, m.f1) == (1.0, 0.0, 0.0)
    assert math.isnan(m.median_position_error_m) and math.isnan(m.kind_accuracy)
    m = match_detections([_det(5.0)], [])
    assert (m.precision, m.recall, m.f1) == (0.0, 1.0, 0.0)


@settings(max_examples=60)
@given(st.lists(st.tuples(st.floats(0, 50), st.sampled_from(["left", "right", "both"])), max_size=8),
       st.lists(st.tuples(st.floats(0, 50), st.sampled_from(["left", "right", "both"])), max_size=8),
       st.floats(0.1, 3.0))
def test_match_properties(d_spec, t_spec, tol):
    dets = [_det(p, s) for p, s in d_spec]
    truth = [Anomaly(p, s, "pothole", 0.05, 0.4) for p, s in t_spec]
    m = match_detections(dets, truth, tolerance=tol)
    assert 0 <= m.n_matched <= min(m.n_true, m.n_detected)
    assert all(0.0 <= getattr(m, k) <= 1.0 for k in ("precision", "recall", "f1"))
    assert all(e <= tol + 1e-9 for e in m.position_errors)
    # Order of the inputs does not change the counts.
    r = match_detections(dets[::-1], truth[::-1], tolerance=tol)
    assert r.n_matched == m.n_matched


# --- study -------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_study():
    exp = ExperimentConfig(n_vehicles=3, segment_length=150.0, anomaly_density=0.04)
    cfg = AnomalyStudyConfig(experiment=exp, n_runs=2, depths=(0.015, 0.04), noise_levels=(0.05, 0.3))
    calls = []
    return cfg, run_anomaly_study(cfg, 4, progress=calls.append), calls


def test_small_study_rows_in_range(small_study, tmp_path):
    cfg, res, calls = small_study
    assert calls == [1, 2]
    assert [r.estimator for r in res.detection_rows] == list(ESTIMATORS)
    assert len(res.depth_rows) == 2 * 3 and len(res.noise_rows) == 2 * 3 and len(res.vehicle_rows) == 3 * 3
    for row in res.detection_rows + res.depth_rows + res.noise_rows + res.vehicle_rows:
        for k in ("precision", "recall", "f1", "kind_accuracy", "side_accuracy"):
            assert 0.0 <= getattr(row, k) <= 1.0, (k, row)
        assert row.median_position_error_m <= cfg.tolerance
        assert row.n_matched <= min(row.n_true, row.n_detected)
    # Vehicles 2..3 pooled: the default-noise sweep point is the default condition itself.
    for est in ESTIMATORS:
        main = next(r for r in res.detection_rows if r.estimator == est)
        sweep = next(r for r in res.noise_rows if r.estimator == est and r.sensor_noise_std == 0.05)
        assert dataclasses.asdict(main) == {k: v for k, v in dataclasses.asdict(sweep).items()
                                            if k != "sensor_noise_std"}
        per_v = [r for r in res.vehicle_rows if r.estimator == est and r.vehicle >= 2]
        assert sum(r.n_true for r in per_v) == main.n_true > 0
        assert sum(r.n_matched for r in per_v) == main.n_matched
    # Vehicle 1 has no predecessor: its collaborative estimate is its observer.
    v1 = {r.estimator: r for r in res.vehicle_rows if r.vehicle == 1}
    assert v1["collaborative"] == dataclasses.replace(v1["observer_only"], estimator="collaborative")
    # Deeper anomalies are easier; the map example holds truth and all estimators.
    f1 = {(r.depth_m, r.estimator): r.f1 for r in res.depth_rows}
    assert all(f1[0.04, e] >= f1[0.015, e] for e in ESTIMATORS)
    ex = res.map_example
    assert ex.vehicle == cfg.map_vehicle and ex.truth and set(ex.detections) == set(ESTIMATORS)

    from roadcollab.reporting import plotting
    for fn, arg in ((plotting.plot_anomaly_map, ex), (plotting.plot_f1_vs_depth, res.depth_rows),
                    (plotting.plot_f1_vs_noise, res.noise_rows)):
        out = fn(arg, tmp_path / f"{fn.__name__}.png")
        assert out.stat().st_size > 5000


def test_study_runs_do_not_depend_on_run_count(small_study):
    cfg, res, _ = small_study
    one = run_anomaly_study(dataclasses.replace(cfg, n_runs=1, depths=(), noise_levels=()), 4)
    assert one.map_example == res.map_example
    assert one.depth_rows == [] and one.noise_rows == []


# --- argument validation -----------------------------------------------------------------------

@pytest.mark.parametrize("kwargs, name", [
    ({"snr_threshold": 0.0}, "snr_threshold"), ({"min_depth": -0.01}, "min_depth"),
    ({"pothole_lengths": ()}, "pothole_lengths"), ({"bump_lengths": (1.0, -2.0)}, "bump_lengths[1]"),
    ({"crosstalk_ratio": 1.0}, "crosstalk_ratio"), ({"noise_floor": 0.0}, "noise_floor"),
    ({"nms_guard": float("nan")}, "nms_guard"), ({"confidence_scale": 0.0}, "confidence_scale"),
])
def test_detector_spec_validation(kwargs, name):
    with pytest.raises(ParameterError, match="^" + re.escape(name)):
        DetectorSpec(**kwargs)


def test_detect_and_match_validation():
    n = 1000
    w, pos = np.zeros((n, 2)), np.arange(n) * SPEED / FS
    bad = [
        (dict(w_hat=np.zeros((n, 3)), positions=pos, speed=SPEED, sample_rate=FS), "w_hat"),
        (dict(w_hat=w[:10], positions=pos[:10], speed=SPEED, sample_rate=FS), "w_hat"),
        (dict(w_hat=np.full((n, 2), np.nan), positions=pos, speed=SPEED, sample_rate=FS), "w_hat"),
        (dict(w_hat=w, positions=pos[:-1], speed=SPEED, sample_rate=FS), "positions"),
        (dict(w_hat=w, positions=2 * pos, speed=SPEED, sample_rate=FS), "positions"),
        (dict(w_hat=w, positions=pos, speed=0.0, sample_rate=FS), "speed"),
        (dict(w_hat=w, positions=pos, speed=SPEED, sample_rate=-1.0), "sample_rate"),
        (dict(w_hat=w, positions=pos, speed=SPEED, sample_rate=FS, spec="default"), "spec"),
    ]
    for kwargs, name in bad:
        w_hat = kwargs.pop("w_hat")
        with pytest.raises(ParameterError, match=rf"^{name}"):
            detect_anomalies(w_hat, **kwargs)
    with pytest.raises(ParameterError, match="^tolerance"):
        match_detections([], TRUTH, tolerance=0.0)
    with pytest.raises(ParameterError, match="^region"):
        match_detections([], TRUTH, region=(40.0, 15.0))
    with pytest.raises(ParameterError, match="^region"):
        match_detections([], TRUTH, region=15.0)
    with pytest.raises(ParameterError, match=r"^truth\[1\]"):
        match_detections([], [TRUTH[0], "pothole"])
    with pytest.raises(ParameterError, match="^detections"):
        match_detections(_det(1.0), TRUTH)
    for kwargs, name in (({"side": "middle"}, "side"), ({"kind": "crack"}, "kind"), ({"depth": 0.0}, "depth"),
                         ({"confidence": 1.5}, "confidence")):
        with pytest.raises(ParameterError, match=f"^{name}"):
            Detection(**{**dict(position=1.0, side="left", kind="pothole", depth=0.01, confidence=0.5), **kwargs})


def test_study_validation():
    exp = ExperimentConfig(n_vehicles=3)
    for kwargs, name in (({"n_runs": 0}, "n_runs"), ({"depths": (0.02, -0.01)}, r"depths\[1\]"),
                         ({"noise_levels": 0.05}, "noise_levels"), ({"tolerance": 0.0}, "tolerance"),
                         ({"map_vehicle": 4}, "map_vehicle"), ({"detector": {}}, "detector"),
                         ({"experiment": ExperimentConfig(n_vehicles=1)}, r"experiment\.n_vehicles")):
        with pytest.raises(ParameterError, match=f"^{name}"):
            AnomalyStudyConfig(**{"experiment": exp, **kwargs})
    cfg = AnomalyStudyConfig(experiment=exp, n_runs=1)
    with pytest.raises(ParameterError, match="^seed"):
        run_anomaly_study(cfg, -1)
    with pytest.raises(ParameterError, match="^config"):
        run_anomaly_study(exp, 0)


def test_measured_profile_with_injected_anomalies():
    """Measured roughness plus synthetic anomalies: ground truth survives and is found."""
    from roadcollab.io.profiles import measured_road
    from roadcollab.models.road import RoadSpec, with_anomalies

    base = measured_road(spacing=0.05, rng=0)
    road = with_anomalies(base, RoadSpec(anomaly_density=0.02, depth_range=(0.05, 0.05)), rng=1)
    assert len(road.anomalies) > 3
    a = next(x for x in road.anomalies if x.kind == "pothole")
    k = int(np.argmin(np.abs(road.distance - a.center)))
    t = a.tracks[0]
    # The pothole floor sits 5 cm below the measured surface there (enveloping keeps the
    # floor for potholes longer than the 0.25 m tyre footprint).
    if a.length > 0.4:
        assert road.elevation[k, t] - base.elevation[k, t] == pytest.approx(-0.05, abs=2e-3)
    cfg = AnomalyStudyConfig(experiment=ExperimentConfig(n_vehicles=3, road_profile="packaged"), n_runs=1,
                             depths=(), noise_levels=())
    res = run_anomaly_study(cfg, 0)
    fused = next(r for r in res.detection_rows if r.estimator == "fused")
    assert fused.n_true > 0 and fused.recall > 0.5
