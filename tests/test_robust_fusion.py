"""Robust fusion, corroborated anomaly maps and one malicious vehicle against the fleet (issue 9, item 2)."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from roadcollab.collaboration.robust_fusion import FUSION_RULES, RobustFusion, fuse_inversions
from roadcollab.detection.corroboration import corroborate, votes
from roadcollab.detection.detector import Detection
from roadcollab.errors import MessageError, ParameterError
from roadcollab.estimation.grid import SegmentGrid
from roadcollab.experiments.anomalies.config import AnomalyStudyConfig
from roadcollab.experiments.security.fusion_poisoning import fusion_poisoning_rows
from roadcollab.wire.message import InversionMessage


def test_rules_on_closed_forms():
    z = np.array([1.0, 2.0, 3.0, 4.0, 100.0])[:, None, None] * np.ones((1, 3, 2))
    assert np.allclose(RobustFusion("mean").combine(z), 22.0)
    assert np.allclose(RobustFusion("median").combine(z), 3.0)
    assert np.allclose(RobustFusion("trimmed_mean", trim=1).combine(z), 3.0)
    # Symmetric honest values around 0 plus nothing else: every location estimate is 0.
    sym = np.array([-2.0, -1.0, 0.0, 1.0, 2.0])[:, None, None] * np.ones((1, 4, 1))
    for rule in FUSION_RULES:
        assert np.allclose(RobustFusion(rule).combine(sym), 0.0, atol=1e-12), rule


def test_identical_contributions_are_returned_exactly():
    rng = np.random.default_rng(0)
    x = rng.standard_normal((50, 2))
    for rule in FUSION_RULES:
        assert np.allclose(RobustFusion(rule).combine(np.stack([x] * 7)), x, rtol=1e-14, atol=0), rule


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(3, 12), rule=st.sampled_from(FUSION_RULES[1:]),
       big=st.sampled_from([1e3, 1e12, 1e300, -1e300]))
def test_bounded_influence(seed, n, rule, big):
    """Up to ``tolerated(n)`` arbitrary contributions move the result by a bounded amount, whatever
    their size: replacing 1e2 by ``big`` changes it by less than the honest spread."""
    fusion = RobustFusion(rule, trim=(n - 1) // 2)
    f = fusion.tolerated(n)
    rng = np.random.default_rng(seed)
    honest = rng.standard_normal((n, 40, 2))
    mild, wild = honest.copy(), honest.copy()
    mild[:f] = 1e2 * np.sign(big)
    wild[:f] = big
    a, b = fusion.combine(mild), fusion.combine(wild)
    assert np.all(np.isfinite(b))
    spread = honest[f:].max(axis=0) - honest[f:].min(axis=0)
    assert np.all(np.abs(a - b) <= spread + 1e-9)


def test_mean_has_no_breakdown():
    assert RobustFusion("mean").tolerated(10) == 0
    z = np.zeros((10, 5, 2))
    z[0] = 1e6
    assert np.allclose(RobustFusion("mean").combine(z), 1e5)
    assert RobustFusion().tolerated(10) == 4 and RobustFusion("trimmed_mean", trim=2).tolerated(10) == 2


def test_bad_arguments():
    with pytest.raises(ParameterError, match="rule"):
        RobustFusion("mode")
    with pytest.raises(ParameterError, match="scale_floor"):
        RobustFusion(scale_floor=0.0)
    with pytest.raises(ParameterError, match="finite"):
        RobustFusion().combine(np.full((3, 4, 2), np.nan))


def _grid():
    return SegmentGrid(n_samples=64, sample_rate=100.0)


def _msg(grid, z, mechanism="hardened", count=1, n_samples=None):
    return InversionMessage(mechanism=mechanism, sample_rate=grid.sample_rate,
                            n_samples=grid.n_samples if n_samples is None else n_samples, z=z, count=count)


def test_fusion_node_refuses_what_buys_weight_or_does_not_fit():
    g = _grid()
    z = np.ones((g.nfft, 2))
    msgs = [_msg(g, z), _msg(g, 2 * z), _msg(g, 3 * z), _msg(g, 1e3 * z, "fused", count=999_999),
            _msg(g, np.ones((g.nfft + 2, 2)))]
    out = fuse_inversions(msgs, g, RobustFusion("median"))
    assert out.used == (0, 1, 2)
    assert [r.index for r in out.refused] == [3, 4]
    assert "count" in out.refused[0].reason or "mechanism" in out.refused[0].reason
    assert np.allclose(out.z, 2.0)
    with pytest.raises(MessageError, match="no usable"):
        fuse_inversions(msgs[3:], g)


def _det(pos, kind="pothole", side="both"):
    return Detection(position=pos, side=side, kind=kind, depth=0.03, confidence=0.9)


def test_corroboration_counts_distinct_vehicles():
    fused = [_det(10.0), _det(50.0), _det(80.0, kind="bump")]
    per_vehicle = [[_det(10.2), _det(10.3)], [_det(9.5), _det(50.0)], [_det(10.9, side="left")],
                   [_det(80.0, kind="pothole")], []]
    assert votes(fused[0], per_vehicle) == 3          # vehicle 0 counts once despite two detections
    assert votes(fused[1], per_vehicle) == 1
    assert votes(fused[2], per_vehicle) == 0          # kinds must agree
    assert corroborate(fused, per_vehicle, min_votes=3) == [fused[0]]
    assert corroborate(fused, per_vehicle, min_votes=1) == fused[:2]
    with pytest.raises(ParameterError, match="min_votes"):
        corroborate(fused, per_vehicle, min_votes=6)


def test_one_malicious_vehicle_cannot_steer_the_robust_map():
    """Against the plain (count-weighted) mean the attacks work; against weighted Huber with
    corroboration they do not (MSE within 1.5 x honest, no fake anomaly, none erased)."""
    rows = fusion_poisoning_rows(AnomalyStudyConfig(), 0, n_runs=1,
                                 strategies=("scale_1e3", "count", "fake_pothole", "erase_potholes"),
                                 targets=("mean", "robust"))
    by = {(r.strategy, r.target): r for r in rows}
    for s in ("scale_1e3", "count", "fake_pothole", "erase_potholes"):
        robust = by[s, "fused_robust"]
        assert robust.ratio <= 1.5, (s, robust)
        assert robust.fake_anomalies_reported == 0 and robust.real_anomalies_lost == 0, (s, robust)
        assert by[s, "fused_mean"].ratio > 10, (s, by[s, "fused_mean"])
    assert by["fake_pothole", "fused_mean"].fake_anomalies_reported >= 1
    assert by["erase_potholes", "fused_mean"].real_anomalies_lost >= 1
    assert by["count", "fused_robust"].refused == 1
