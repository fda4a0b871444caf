"""Tests of roadcollab.models.road: ISO 8608 roughness, anomalies, sampling and measured profiles."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roadcollab.errors import ParameterError
from roadcollab.io.profiles import load_profile, measured_road, packaged_profile_path
from roadcollab.models.anomaly import Anomaly
from roadcollab.models.profile import RoadProfile
from roadcollab.models.road import (
    ISO_8608_GD0,
    JumpStatistics,
    RoadSpec,
    generate_road,
    jump_statistics,
    road_velocity_psd,
    wiener_intensity,
)

N0 = 0.1


@pytest.fixture(scope="module")
def long_smooth_road():
    """20 km of class C, no anomalies, no enveloping: 400,000 increments per track."""
    spec = RoadSpec(length=20_000.0, spacing=0.05, iso_class="C", anomaly_density=0.0, enveloping_length=0.0)
    return spec, generate_road(spec, rng=2024)


# --- ISO 8608 roughness -----------------------------------------------------------------------

def test_random_walk_increment_variance(long_smooth_road):
    spec, road = long_smooth_road
    inc = np.diff(road.elevation, axis=0)
    expected = 2 * math.pi**2 * N0**2 * ISO_8608_GD0["C"] * spec.spacing
    # The mean-square of n = 4e5 Gaussian increments has relative sd sqrt(2/n) = 0.22 %; 1.5 % is ~7 sd.
    np.testing.assert_allclose(np.mean(inc**2, axis=0), expected, rtol=0.015)
    np.testing.assert_array_equal(road.elevation[0], 0.0)
    # Independent tracks: the correlation estimate has sd 1/sqrt(n) = 0.0016.
    assert abs(np.corrcoef(inc.T)[0, 1]) < 0.01
    # Gaussian increments: kurtosis 3 with sd sqrt(24/n) = 0.008.
    kurt = np.mean(inc**4, axis=0) / np.mean(inc**2, axis=0) ** 2
    np.testing.assert_allclose(kurt, 3.0, atol=0.05)


def test_road_velocity_psd_closed_form():
    expected = 4 * math.pi**2 * 0.01 * 256e-6 * 15
    assert road_velocity_psd("C", 15) == pytest.approx(expected, rel=1e-12)
    assert road_velocity_psd(256e-6, 15.0) == pytest.approx(expected, rel=1e-12)
    assert road_velocity_psd("c", 15) == pytest.approx(expected, rel=1e-12)
    # Each class quadruples Gd(n0).
    assert road_velocity_psd("D", 15) == pytest.approx(4 * expected, rel=1e-12)
    np.testing.assert_allclose(wiener_intensity("C", 15), 0.5 * expected * np.eye(2), rtol=1e-12)
    np.testing.assert_allclose(wiener_intensity(RoadSpec(iso_class="C"), 15), 0.5 * expected * np.eye(2), rtol=1e-12)


def test_sampled_velocity_variance_matches_wiener_intensity(long_smooth_road):
    spec, road = long_smooth_road
    speed, fs = 20.0, 400.0   # one sample per 0.05 m grid step
    velocity = road.sample(speed, fs).velocity
    q = wiener_intensity(spec, speed)
    # White velocity held over 1/fs has variance q * fs; 4e5 samples per track -> sd 0.22 %.
    np.testing.assert_allclose(np.mean(velocity**2, axis=0), np.diag(q) * fs, rtol=0.015)


# --- anomalies and generation ------------------------------------------------------------------

def _anomaly_spec(**kw):
    base = dict(length=400.0, iso_class="A", anomaly_density=0.05, enveloping_length=0.0)
    base.update(kw)
    return RoadSpec(**base)


@pytest.mark.parametrize("seed", range(6))
def test_anomaly_ground_truth_matches_profile(seed):
    spec = _anomaly_spec()
    road = generate_road(spec, rng=seed)
    # Same seed without anomalies: the random walk is drawn first, so the difference is the anomalies.
    bare = generate_road(_anomaly_spec(anomaly_density=0.0), rng=seed)
    diff = road.elevation - bare.elevation
    x = road.distance
    covered = np.zeros_like(diff, dtype=bool)
    assert len(road.anomalies) > 0
    for a in road.anomalies:
        assert spec.anomaly_margin <= a.position and a.end <= spec.length - spec.anomaly_margin
        assert spec.depth_range[0] <= a.depth <= spec.depth_range[1]
        assert a.center == pytest.approx(a.position + a.length / 2)
        inside = (x >= a.position) & (x < a.end)
        for col in a.tracks:
            covered[(x >= a.position) & (x <= a.end), col] = True
            if a.kind == "pothole":
                assert spec.pothole_length_range[0] <= a.length <= spec.pothole_length_range[1]
                np.testing.assert_allclose(diff[inside, col], -a.depth, rtol=1e-12)
                # The edges are also visible on the rough road: class A moves < 0.4 mm per 5 cm step.
                i0, i1 = np.flatnonzero(inside)[[0, -1]]
                sd_step = math.sqrt(2 * math.pi**2 * N0**2 * ISO_8608_GD0["A"] * spec.spacing)
                assert road.elevation[i0, col] - road.elevation[i0 - 1, col] == pytest.approx(-a.depth, abs=6 * sd_step)
                assert road.elevation[i1 + 1, col] - road.elevation[i1, col] == pytest.approx(a.depth, abs=6 * sd_step)
            else:
                assert spec.bump_length_range[0] <= a.length <= spec.bump_length_range[1]
                # The grid point nearest the centre is within delta = spacing/2 of it, where the
                # raised cosine is depth * cos(pi * delta / length)^2.
                peak = diff[inside, col].max()
                assert a.depth * math.cos(math.pi * spec.spacing / (2 * a.length)) ** 2 <= peak <= a.depth
                assert np.all(diff[inside, col] >= 0)
    # Nothing anywhere else.
    np.testing.assert_array_equal(diff[~covered], 0.0)
    # Anomalies sharing a track keep the minimum clear gap.
    for col in (0, 1):
        mine = [a for a in road.anomalies if col in a.tracks]
        for prev, nxt in zip(mine, mine[1:]):
            assert nxt.position - prev.end >= spec.min_anomaly_gap


def test_anomaly_shapes():
    pothole = Anomaly(1.0, "left", "pothole", 0.05, 0.5)
    # Rectangular and half-open, so the edges are single jumps of -depth and +depth.
    np.testing.assert_array_equal(pothole.elevation([0.99, 1.0, 1.25, 1.49, 1.5]), [0, -0.05, -0.05, -0.05, 0])
    bump = Anomaly(2.0, "both", "bump", 0.04, 2.0)
    np.testing.assert_allclose(bump.elevation([1.9, 2.0, 2.5, 3.0, 3.5, 4.0, 4.1]),
                               [0, 0, 0.02, 0.04, 0.02, 0, 0], atol=1e-15)
    assert bump.center == 3.0 and bump.end == 4.0 and bump.tracks == (0, 1)


def test_enveloping_is_centred_moving_average():
    raw = generate_road(_anomaly_spec(), rng=7)
    env = generate_road(_anomaly_spec(enveloping_length=0.25), rng=7)
    # Oracle: 5-sample (0.25 m / 0.05 m) centred mean with the end values replicated.
    padded = np.pad(raw.elevation, ((2, 2), (0, 0)), mode="edge")
    expected = np.column_stack([np.convolve(padded[:, c], np.ones(5) / 5, mode="valid") for c in range(2)])
    np.testing.assert_allclose(env.elevation, expected, atol=1e-12)
    assert env.anomalies == raw.anomalies


def test_same_seed_same_road_different_seed_different_road():
    spec = RoadSpec()
    a, b, c = generate_road(spec, rng=5), generate_road(spec, rng=5), generate_road(spec, rng=6)
    np.testing.assert_array_equal(a.elevation, b.elevation)
    assert a.anomalies == b.anomalies
    assert not np.allclose(a.elevation, c.elevation)
    assert a.anomalies != c.anomalies
    assert a.source == "synthetic ISO C"
    assert a.distance.shape == (6601,) and a.elevation.shape == (6601, 2)
    np.testing.assert_allclose(np.diff(a.distance), 0.05)
    with pytest.raises(ValueError):
        a.elevation[0, 0] = 1.0   # read-only: a frozen profile cannot be mutated in place


def test_jump_statistics_closed_form():
    js = jump_statistics(RoadSpec(), 15.0)
    lo, hi = 0.025, 0.10
    depth_sq = (lo**2 + lo * hi + hi**2) / 3
    assert js.rate == pytest.approx(2 * 0.02 * 0.5 * (0.4 + 0.2) * 15)
    np.testing.assert_array_equal(js.mean, 0.0)
    np.testing.assert_allclose(js.covariance, depth_sq * np.array([[1, 1 / 3], [1 / 3, 1]]), rtol=1e-12)
    # Asymmetric sides: rate * covariance is still the exact second-moment intensity.
    spec = RoadSpec(side_probabilities=(0.7, 0.1, 0.2))
    js = jump_statistics(spec, 10.0)
    exact = 2 * 0.02 * 0.5 * 10 * depth_sq * np.array([[0.9, 0.2], [0.2, 0.3]])
    np.testing.assert_allclose(js.intensity, exact, rtol=1e-12)


def test_jump_statistics_match_simulated_pothole_edges():
    spec = RoadSpec(length=100_000.0, spacing=0.5, enveloping_length=0.0)
    road = generate_road(spec, rng=11)
    speed = 12.0
    span = spec.length - 2 * spec.anomaly_margin
    expected_count = spec.anomaly_density * span
    # Poisson count (the gap is enforced by redrawing positions, not dropping): 4 sd.
    assert abs(len(road.anomalies) - expected_count) < 4 * math.sqrt(expected_count)
    second = np.zeros((2, 2))
    for a in road.anomalies:
        if a.kind == "pothole":
            hit = np.isin([0, 1], a.tracks).astype(float)
            second += 2 * a.depth**2 * np.outer(hit, hit)   # a down and an up edge
    empirical = second / (span / speed)
    # ~600 potholes per track (rel. sd ~5 %) and ~200 on both (~9 %): 30 % is > 3 sd.
    np.testing.assert_allclose(empirical, jump_statistics(spec, speed).intensity, rtol=0.3)


# --- sampling in time --------------------------------------------------------------------------

def test_sample_velocity_integrates_back_to_elevation():
    road = generate_road(RoadSpec(), rng=3)
    tr = road.sample(13.7, 250.0, start=20.0, duration=10.0)
    assert tr.elevation.shape == (2501, 2) and tr.velocity.shape == (2500, 2) and tr.time.shape == (2500,)
    rebuilt = tr.elevation[0] + np.cumsum(tr.velocity, axis=0) / tr.sample_rate
    np.testing.assert_allclose(rebuilt, tr.elevation[1:], atol=1e-12)
    np.testing.assert_allclose(tr.positions[:-1], 20.0 + 13.7 * tr.time)
    assert tr.position(2500) == pytest.approx(20.0 + 137.0)
    # Window anomalies: exactly those overlapping [20, 157] m.
    expected = tuple(a for a in road.anomalies if a.end >= 20.0 and a.position <= 157.0)
    assert tr.anomalies == expected


def test_sample_keeps_anomalies_overlapping_the_window():
    x = np.arange(0.0, 100.0 + 1e-9, 0.1)
    anomalies = (Anomaly(5.0, "left", "pothole", 0.05, 1.0),     # before the window
                 Anomaly(19.5, "right", "bump", 0.03, 1.0),      # straddles its start
                 Anomaly(40.0, "both", "pothole", 0.05, 0.5),    # inside
                 Anomaly(59.8, "left", "bump", 0.03, 2.0),       # straddles its end
                 Anomaly(70.0, "left", "pothole", 0.05, 0.5))    # after
    road = RoadProfile(x, np.zeros((x.size, 2)), anomalies, "test")
    tr = road.sample(10.0, 100.0, start=20.0, duration=4.0)       # window [20, 60] m
    assert tr.anomalies == anomalies[1:4]


@settings(max_examples=60, deadline=None)
@given(slope=st.floats(-0.5, 0.5), offset=st.floats(-10, 10), speed=st.floats(1.0, 40.0),
       fs=st.floats(20.0, 2000.0), start=st.floats(0.0, 50.0))
def test_sample_exact_for_linear_profile(slope, offset, speed, fs, start):
    x = np.cumsum(np.r_[0.0, np.linspace(0.05, 0.3, 999)])   # non-uniform grid, ~175 m
    road = RoadProfile(x, np.column_stack([offset + slope * x, offset - 2 * slope * x]))
    tr = road.sample(speed, fs, start=start)
    pos = tr.positions
    assert pos[-1] <= x[-1] + 1e-9 and pos[-1] > x[-1] - speed / fs - 1e-9   # default: to the end
    np.testing.assert_allclose(tr.elevation[:, 0], offset + slope * pos, atol=1e-9)
    np.testing.assert_allclose(tr.elevation[:, 1], offset - 2 * slope * pos, atol=1e-9)
    np.testing.assert_allclose(tr.velocity, np.tile([slope * speed, -2 * slope * speed], (len(tr.time), 1)),
                               atol=1e-6 * fs)


def test_sample_window_validation():
    road = generate_road(RoadSpec(length=100.0), rng=0)
    with pytest.raises(ParameterError, match=r"duration must keep the window inside the profile"):
        road.sample(10.0, 100.0, start=50.0, duration=6.0)
    with pytest.raises(ParameterError, match=r"start must lie in the profile"):
        road.sample(10.0, 100.0, start=-1.0)
    with pytest.raises(ParameterError, match=r"start must lie in the profile"):
        road.sample(10.0, 100.0, start=100.0)
    with pytest.raises(ParameterError, match=r"speed must be > 0"):
        road.sample(0.0, 100.0)
    with pytest.raises(ParameterError, match=r"duration must cover at least one sample"):
        road.sample(10.0, 100.0, duration=0.001)
    assert road.sample(10.0, 100.0, start=50.0, duration=5.0).elevation.shape == (501, 2)


# --- measured profiles -------------------------------------------------------------------------

def test_load_packaged_profile():
    prof = load_profile(packaged_profile_path())
    assert len(prof) == 2177 and prof.distance.shape == (2177,) and prof.elevation.shape == (2177,)
    assert prof.spacing == pytest.approx(0.25, rel=1e-9)
    assert prof.distance[0] == 478.0 and prof.distance[-1] == 1022.0
    assert prof.elevation[0] == pytest.approx(583.1370)


def test_load_profile_formats(tmp_path):
    path = tmp_path / "ok.csv"
    rows = "\n".join(f"{0.5 * i:.4f}, {0.01 * i * i:.6f}  # row {i}" for i in range(10))
    path.write_text("# distance_m,elevation_m\n\n" + rows + "\n\n")
    prof = load_profile(path)
    np.testing.assert_allclose(prof.distance, 0.5 * np.arange(10))
    np.testing.assert_allclose(prof.elevation, 0.01 * np.arange(10) ** 2)
    assert prof.spacing == pytest.approx(0.5)


@pytest.mark.parametrize("bad_line, message", [
    ("2.0 0.1 7", r"line 5: expected 2 numbers 'distance_m elevation_m', got '2.0 0.1 7'"),
    ("2.0 abc", r"line 5: expected 2 numbers 'distance_m elevation_m'"),
    ("2.0 nan", r"line 5: expected finite numbers"),
    ("1.5 0.1", r"line 5: expected distance > 1.5 \(increasing\)"),
    ("2.2 0.1", r"line 5: expected uniform spacing 0.5 m, got step 0.7 m"),
    ("2.0001 0.1", r"line 5: expected uniform spacing 0.5 m, got step 0.5001 m"),   # 2e-4 relative
])
def test_load_profile_errors_name_file_and_line(tmp_path, bad_line, message):
    lines = ["# header", "0.5 0.0", "1.0 0.0", "1.5 0.0", bad_line] + [f"{0.5 * i} 0.0" for i in range(5, 12)]
    path = tmp_path / "bad.txt"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ParameterError, match=r"bad\.txt: " + message):
        load_profile(path)


def test_load_profile_too_short_or_missing(tmp_path):
    path = tmp_path / "short.txt"
    path.write_text("".join(f"{i} 0\n" for i in range(7)))
    with pytest.raises(ParameterError, match=r"short\.txt: expected at least 8 data rows, got 7"):
        load_profile(path)
    with pytest.raises(ParameterError, match=r"missing\.txt: profile file not found"):
        load_profile(tmp_path / "missing.txt")


def test_measured_road_tracks():
    raw = load_profile(packaged_profile_path())
    same = measured_road(second_track="same", detrend=False)
    assert same.source == "profile_1.txt" and same.anomalies == ()
    np.testing.assert_allclose(same.distance, raw.distance - 478.0)
    # 0.25 m enveloping on a 0.25 m grid is a 1-sample window, i.e. the profile itself.
    np.testing.assert_array_equal(same.elevation[:, 0], raw.elevation)
    np.testing.assert_array_equal(same.elevation[:, 0], same.elevation[:, 1])

    detrended = measured_road(second_track="same")
    slope, offset = np.polyfit(detrended.distance, detrended.elevation[:, 0], 1)
    assert abs(slope) < 1e-12 and abs(offset) < 1e-9

    synth_a = measured_road(second_track="synthetic", rng=1)
    synth_b = measured_road(second_track="synthetic", rng=1)
    np.testing.assert_array_equal(synth_a.elevation, synth_b.elevation)
    np.testing.assert_array_equal(synth_a.elevation[:, 0], detrended.elevation[:, 0])
    assert np.corrcoef(synth_a.elevation.T)[0, 1] < 0.9


def test_measured_road_lateral_residual_variance():
    # Brownian motion minus its centred W-metre mean has variance sigma^2 W / 12 (sigma^2 in m^2/m);
    # the 0.25 m grid gives an 81-sample (20.25 m) window. Averaged over 20 seeds the relative sd
    # is ~3 %, so 15 % is ~5 sd. Ends are skipped because there the window is edge-replicated.
    sigma2 = 2 * math.pi**2 * N0**2 * ISO_8608_GD0["A"]
    ms = [np.mean(np.diff(measured_road(rng=s, enveloping_length=0.0).elevation, axis=1)[40:-40] ** 2)
          for s in range(20)]
    assert np.mean(ms) == pytest.approx(sigma2 * 20.25 / 12, rel=0.15)


def test_measured_road_resampling():
    coarse = measured_road(second_track="same")
    fine = measured_road(second_track="same", spacing=0.05, enveloping_length=0.0)
    np.testing.assert_allclose(np.diff(fine.distance), 0.05, atol=1e-9)
    assert fine.distance[-1] == pytest.approx(544.0)
    np.testing.assert_allclose(fine.elevation[::5, 0], coarse.elevation[:, 0], atol=1e-12)


# --- parameter validation ----------------------------------------------------------------------

@pytest.mark.parametrize("kwargs, message", [
    (dict(length=-1.0), r"length must be > 0, got -1"),
    (dict(iso_class="Z"), r"iso_class must be an ISO 8608 class in A..H, got 'Z'"),
    (dict(depth_range=(0.1, 0.02)), r"depth_range must have low <= high, got \(0.1, 0.02\)"),
    (dict(side_probabilities=(0.5, 0.5, 0.5)), r"side_probabilities must sum to 1, got 1.5"),
    (dict(side_probabilities=(0.5, 0.5)), r"side_probabilities must be \(left, right, both\)"),
    (dict(pothole_fraction=1.5), r"pothole_fraction must be <= 1"),
    (dict(spacing=200.0), r"spacing must be <= length / 2"),
    (dict(length=40.0, anomaly_margin=19.0), r"anomaly_margin must leave room"),
    (dict(enveloping_length=-0.1), r"enveloping_length must be >= 0"),
])
def test_road_spec_rejects_bad_parameters(kwargs, message):
    with pytest.raises(ParameterError, match=message):
        RoadSpec(**kwargs)


def test_other_bad_parameters():
    with pytest.raises(ParameterError, match=r"iso_class_or_gd0 must be an ISO 8608 class"):
        road_velocity_psd("Q", 10.0)
    with pytest.raises(ParameterError, match=r"speed must be > 0"):
        road_velocity_psd("C", -1.0)
    with pytest.raises(ParameterError, match=r"side must be one of"):
        Anomaly(10.0, "middle", "pothole", 0.05, 0.5)
    with pytest.raises(ParameterError, match=r"depth must be > 0"):
        Anomaly(10.0, "left", "bump", -0.05, 0.5)
    with pytest.raises(ParameterError, match=r"second_track must be"):
        measured_road(second_track="mirror")
    with pytest.raises(ParameterError, match=r"lateral_class must be an ISO 8608 class"):
        measured_road(lateral_class="X")
    with pytest.raises(ParameterError, match=r"spacing must lie in"):
        measured_road(spacing=1000.0)
    with pytest.raises(ParameterError, match=r"covariance must be positive semi-definite"):
        JumpStatistics(1.0, np.zeros(2), np.array([[1.0, 2.0], [2.0, 1.0]]))
    with pytest.raises(ParameterError, match=r"distance must be strictly increasing"):
        RoadProfile(np.array([0.0, 1.0, 1.0]), np.zeros((3, 2)))
    with pytest.raises(ParameterError, match=r"elevation must have shape \(3, 2\)"):
        RoadProfile(np.arange(3.0), np.zeros((3, 1)))


def test_measured_road_from_a_profile_already_read_equals_reading_the_file():
    profile = load_profile(packaged_profile_path())
    for kw in ({}, {"spacing": 0.05}, {"second_track": "synthetic", "detrend": False}):
        a = measured_road(profile, rng=3, **kw)
        b = measured_road(None, rng=3, **kw)
        assert np.array_equal(a.elevation, b.elevation) and np.array_equal(a.distance, b.distance)
        assert a.source == b.source == "profile_1.txt"
    assert np.array_equal(profile.elevation, load_profile(packaged_profile_path()).elevation)   # not modified
