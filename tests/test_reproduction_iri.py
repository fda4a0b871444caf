"""Estimated against true IRI in ``roadcollab reproduce``: integration, ratios, the measured runs."""

import numpy as np
import pytest

import roadcollab as rc
from roadcollab.experiments.reproduction.study import ESTIMATORS, run_reproduction
from roadcollab.experiments.reproduction.iri import elevation_with_end, iri_ratios, iri_rows, run_iri
from roadcollab.io.profiles import measured_road
from roadcollab.models.iri import iri_segments
from roadcollab.models.profile import RoadProfile


def _sinusoid_road(speed=15.0, fs=200.0, length=120.0):
    """Two tracks of 5 mm sinusoids (5 m and 8 m wavelengths) seen at ``speed``."""
    x = np.arange(0.0, length + 1.0, 0.025)
    z = np.column_stack([5e-3 * np.sin(2 * np.pi * x / 5.0), 5e-3 * np.sin(2 * np.pi * x / 8.0 + 1.0)])
    return RoadProfile(x, z).sample(speed, fs, duration=length / speed)


def test_integrated_velocity_is_the_road_elevation():
    road = _sinusoid_road()
    h = elevation_with_end(road.velocity, road.sample_rate)
    assert h.shape == road.elevation.shape
    np.testing.assert_allclose(np.diff(h, axis=0), np.diff(road.elevation, axis=0), rtol=0, atol=1e-15)
    want = iri_segments(road.positions, road.elevation, 40.0)
    got = iri_segments(road.positions, h, 40.0)
    assert want.start.size == 3  # N samples give N + 1 elevations: the whole 120 m, not 119.9 m
    np.testing.assert_allclose(got.left, want.left, rtol=1e-9)
    np.testing.assert_allclose(got.right, want.right, rtol=1e-9)


def test_iri_is_positively_homogeneous_so_ratios_are_the_scale_factors():
    road = _sinusoid_road()
    w = road.velocity
    estimates = {name: (1.0 + 0.1 * i) * w for i, name in enumerate(ESTIMATORS)}
    res = run_iri(road.positions, w, w, estimates, sample_rate=road.sample_rate, vehicle=2, segment_length=40.0)
    assert res.truth_raw.shape == (3, 2) and np.all(res.truth_raw > 1.0)
    np.testing.assert_array_equal(res.truth_band, res.truth_raw)
    rows = iri_rows([None, res])
    assert len(rows) == 2 * 3 and {r.run for r in rows} == {1} and rows[0].track == "left"
    assert [r.start_m for r in rows[:3]] == pytest.approx([0.0, 40.0, 80.0])
    for i, r in enumerate(x for x in iri_ratios(rows, ESTIMATORS) if x.track == "both"):
        assert r.estimator == ESTIMATORS[i] and r.segments == 6
        assert r.ratio_raw == pytest.approx(1.0 + 0.1 * i, rel=1e-9)
        assert r.ratio_band == pytest.approx(1.0 + 0.1 * i, rel=1e-9)
        assert r.ratio_raw_std < 1e-9


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_measured_runs_compare_estimated_with_true_iri():
    cfg = rc.ExperimentConfig(n_vehicles=2, n_runs=1, road_profile="packaged")
    res = run_reproduction(cfg, 0, iri_segment_length=50.0)
    rows = res.iri_rows()
    assert len(rows) == 2 * 6 and {r.vehicle for r in rows} == {2}
    left = [r for r in rows if r.track == "left"]
    assert [r.start_m for r in left] == pytest.approx(cfg.margin + 50.0 * np.arange(6))
    # The left track is the measured one (the rng draws only the right): its raw truth is independent of the run.
    road = measured_road(rng=0).sample(cfg.speed, cfg.sample_rate, duration=cfg.n_samples / cfg.sample_rate)
    sl = cfg.scored
    want = iri_segments(road.positions[sl.start:sl.stop + 1], road.elevation[sl.start:sl.stop + 1, 0], 50.0)
    np.testing.assert_allclose([r.true_iri_raw for r in left], want.left, rtol=1e-9)
    # The band limit (> 30 m) costs the truth only a few per cent of its IRI, and the per-bin oracle recovers it.
    band = np.array([r.true_iri_band_limited / r.true_iri_raw for r in rows])
    assert np.all((band > 0.9) & (band < 1.02))
    ratios = {(r.estimator, r.track): r for r in iri_ratios(rows, ESTIMATORS)}
    assert ratios["oracle_per_bin", "both"].ratio_band == pytest.approx(1.0, abs=0.02)
    assert res.runs[0].iri is not None and run_reproduction(cfg, 0).iri_rows() == []
