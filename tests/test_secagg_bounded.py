"""Phased, centred clipping inside secure aggregation: the study node (issue 20, section 2)."""

from __future__ import annotations

import numpy as np

from roadcollab.experiments.anomalies.config import AnomalyStudyConfig
from roadcollab.experiments.security.fusion_poisoning import fusion_poisoning_rows
from roadcollab.experiments.security.secagg_bounded import ball_radius, centred_clipping


def test_honest_inputs_inside_the_ball_give_their_mean():
    gen = np.random.default_rng(0)
    us = list(gen.normal(0, 1, (10, 50)))
    m, clipped = centred_clipping(us, us, radius=100.0, phases=5)
    assert clipped == 0 and np.allclose(m, np.mean(us, axis=0), atol=1e-12)


def test_one_vehicle_moves_the_fixed_point_by_about_r_over_n_minus_1():
    gen = np.random.default_rng(1)
    n, R = 10, 1.0
    us = list(gen.normal(0, 0.05, (n, 40)))
    honest = np.mean(us[1:], axis=0)
    lie = np.full(40, 1e6)
    first = [np.clip(lie, -5, 5)] + us[1:]          # its phase-1 input clipped into a road-sized box
    m, _ = centred_clipping(first, [lie] + us[1:], R, phases=30)
    shift = float(np.linalg.norm(m - honest))
    assert shift <= 1.05 * R / (n - 1)
    m1 = np.mean(first, axis=0)                     # one phase: the road-sized shift of the wide box
    assert float(np.linalg.norm(m1 - honest)) > 10 * shift


def test_the_radius_is_the_stated_multiple():
    C = np.full((4, 2), 0.5)
    assert np.isclose(ball_radius(C, 10, kappa2=0.25), np.sqrt(0.25 * 0.9 * 4.0))


def test_the_bounded_node_keeps_every_strategy_within_2x_where_the_box_does_not():
    rows = fusion_poisoning_rows(AnomalyStudyConfig(), 0, n_runs=1, strategies=("scale_10", "fake_pothole"),
                                 targets=("secagg_valid", "secagg_bounded"))
    got = {(r.target, r.strategy): r for r in rows}
    assert got["fused_secagg_valid", "scale_10"].ratio > 10            # the road-sized box
    bounded = [r for r in rows if r.target == "fused_secagg_bounded"]
    assert {r.strategy for r in bounded} >= {"scale_10", "adaptive_fake", "adaptive_erase", "adaptive_anti_road"}
    for r in bounded:
        assert r.ratio <= 2.0, r
        assert r.fake_anomalies_reported == 0 and r.real_anomalies_lost == 0, r
