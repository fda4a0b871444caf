"""Tests written for the survivors of the mutation pass (docs/mutation.md), from hand-derivable inputs."""

import math

import numpy as np
import pytest

from roadcollab.detection.detector import Detection
from roadcollab.detection.scoring import MatchTally, match_detections
from roadcollab.errors import ParameterError
from roadcollab.estimation.grid import SegmentGrid, bin_index
from roadcollab.models.road import Anomaly

TRUTH = [Anomaly(9.75, "left", "pothole", 0.05, 0.5), Anomaly(29.75, "right", "bump", 0.04, 0.5)]   # centers 10, 30


def _det(x, side="left", kind="pothole", depth=0.05):
    return Detection(position=x, side=side, kind=kind, depth=depth, confidence=0.9)


def test_tally_pools_counts_and_pairs_of_every_result():
    # Run 1: both found, the second on the wrong side ("both" is compatible) and of the wrong kind, one false
    # positive. Run 2: only the first, 0.5 m off, depth 0.04 (relative error 0.2).
    r1 = match_detections([_det(10.25), _det(30.0, side="both", kind="pothole"), _det(50.0)], TRUTH)
    r2 = match_detections([_det(10.5, depth=0.04)], TRUTH)
    tally = MatchTally()
    tally.add(r1)
    tally.add(r2)
    s = tally.scores()
    assert (s.n_true, s.n_detected, s.n_matched) == (4, 4, 3)
    assert (s.precision, s.recall) == (0.75, 0.75)
    assert s.kind_accuracy == pytest.approx(2 / 3) and s.side_accuracy == pytest.approx(2 / 3)
    assert s.median_position_error_m == 0.25                   # of 0.25, 0.0, 0.5
    assert s.median_depth_rel_error == pytest.approx(0.1)      # of 0.0 and 0.2 (same-kind pairs only)


def test_empty_tally_has_nan_agreement_and_perfect_precision_recall():
    s = MatchTally().scores()
    assert (s.precision, s.recall, s.n_matched) == (1.0, 1.0, 0)
    assert math.isnan(s.kind_accuracy) and math.isnan(s.side_accuracy) and math.isnan(s.median_depth_rel_error)


def test_bin_index_is_a_slice_exactly_for_contiguous_masks():
    m = np.zeros(10, bool)
    m[3:7] = True
    assert bin_index(m) == slice(3, 7)
    m[8] = True
    assert bin_index(m) is m
    m = np.zeros(10, bool)
    m[[0, 1]] = True
    assert bin_index(m) == slice(0, 2)


def test_band_limit_returns_n_samples_and_names_x_in_errors():
    g = SegmentGrid(400, 100.0, band_low_hz=1.0)
    x = np.random.default_rng(1).standard_normal((400, 2))
    assert g.band_limit(x).shape == (400, 2)
    assert g.band_limit(x, 250).shape == (250, 2)
    np.testing.assert_array_equal(g.band_limit(x, 250), g.band_limit(x)[:250])
    with pytest.raises(ParameterError, match="^x "):
        g.band_limit(np.full((400, 2), np.nan))


# --- survivors of the pass over collaboration/guard.py and detection/ (docs/mutation.md) ---------------------

def test_corroboration_agrees_by_center_distance_kind_and_a_shared_track():
    from roadcollab.detection.corroboration import confirmed_by_own

    msg = [_det(100.0), _det(200.0, side="right", kind="bump"), _det(300.0, side="both")]
    # own detections: 0.5 m from the first (agrees), the second on the other track (does not), the third
    # 1.5 m away (does not at tolerance 1 m); and one far away whose sum with a message's center would be small.
    own = [_det(100.5), _det(200.0, side="left", kind="bump"), _det(301.5, side="both"), _det(-100.0)]
    assert confirmed_by_own(msg, own) == [msg[0]]
    assert confirmed_by_own([_det(100.0)], [_det(-100.0)]) == []          # |a - b| = 200, |a + b| = 0
    assert confirmed_by_own([_det(100.0)], [_det(100.0, kind="bump")]) == []
    exact = _det(101.0)
    assert confirmed_by_own([_det(100.0)], [exact], tolerance=1.0)          # the boundary is inclusive


def test_detector_confidence_is_the_stated_logistic_of_the_snr():
    from roadcollab.detection.detector import DetectorSpec

    spec = DetectorSpec()
    mid, scale = spec.confidence_mid, spec.confidence_scale
    snr = np.array([mid - 2 * scale, mid, mid + scale])
    expected = 1.0 / (1.0 + np.exp(-(snr - mid) / scale))
    np.testing.assert_allclose(spec.confidence(snr), expected, rtol=1e-12)
    assert spec.confidence(mid) == 0.5


# --- detector._merge_tracks (third pass, docs/mutation.md): the stated pairing rule of the module docstring,
# step 5: left/right detections whose centers are within merge_tolerance pair closest first; a pair is cross-talk
# when the weaker depth is *below* crosstalk_ratio times the stronger; else it merges if the kinds agree; a
# detection pairs at most once; the rest are reported one-sided. Candidates are (snr, kind, start, length, depth).

def _cand(center, depth=0.05, kind="pothole", length=0.5, snr=8.0):
    return (snr, kind, center - 0.5 * length, length, depth)


def _sides(dets):
    return sorted((d.side, d.position) for d in dets)


def test_merge_pairs_the_closest_centers_first_and_each_detection_once():
    from roadcollab.detection.detector import DetectorSpec, _merge_tracks
    spec = DetectorSpec()
    # Right candidates 0.25 m and 0.375 m from the left one (both within 0.5 m): the closer one merges.
    out = _merge_tracks([[_cand(10.0)], [_cand(9.625), _cand(10.25)]], spec)
    assert _sides(out) == [("both", 10.125), ("right", 9.625)]
    # A pair skipped because its left member is taken does not end the pairing: a later, farther pair merges.
    out = _merge_tracks([[_cand(10.0), _cand(30.0)], [_cand(9.625), _cand(10.25), _cand(30.4375)]], spec)
    assert _sides(out) == [("both", 10.125), ("both", 30.21875), ("right", 9.625)]


def test_merge_keeps_the_sides_apart_when_checking_what_is_taken():
    from roadcollab.detection.detector import DetectorSpec, _merge_tracks
    # Left 0 pairs with right 1 first; left 1 must still pair with right 0 (index 1 is taken only on the right).
    out = _merge_tracks([[_cand(10.0), _cand(20.0)], [_cand(20.125), _cand(10.0625)]], DetectorSpec())
    assert _sides(out) == [("both", 10.03125), ("both", 20.0625)]


def test_merge_tolerance_and_crosstalk_ratio_boundaries():
    from roadcollab.detection.detector import DetectorSpec, _merge_tracks
    spec = DetectorSpec()
    far = spec.merge_tolerance          # 0.5 m, exact in binary: centers exactly that far apart merge
    assert _sides(_merge_tracks([[_cand(10.0)], [_cand(10.0 + far)]], spec)) == [("both", 10.0 + far / 2)]
    # Weaker depth exactly crosstalk_ratio times the stronger: not below it, so not cross-talk: merged.
    d = 0.5
    out = _merge_tracks([[_cand(10.0, depth=d)], [_cand(10.0, depth=spec.crosstalk_ratio * d)]], spec)
    assert _sides(out) == [("both", 10.0)]
    # Just below it: cross-talk, only the stronger side is reported.
    out = _merge_tracks([[_cand(10.0, depth=d)], [_cand(10.0, depth=0.99 * spec.crosstalk_ratio * d)]], spec)
    assert _sides(out) == [("left", 10.0)]
