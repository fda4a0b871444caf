"""Per-vehicle IRI gain calibration (experiments/drives/gain_calibration.py): closed-form oracles."""

import math

import numpy as np
import pytest

from roadcollab.experiments.drives.gain_calibration import calibrate_gains


def _obs(gains: dict, segments: dict, driven: dict, noise=None):
    """Exact observations g_v * I_s (times exp(noise) per observation, if given)."""
    out = []
    for v, segs in driven.items():
        for s in segs:
            e = 0.0 if noise is None else float(noise.normal(0.0, 0.03))
            out.append((v, s, gains[v] * segments[s] * math.exp(e)))
    return out


def test_exact_gains_are_recovered_relative_to_the_fleets_geometric_mean():
    rng = np.random.default_rng(1)
    g = {f"v{i}": float(x) for i, x in enumerate(np.exp(rng.normal(0.0, 0.15, 6)))}
    segs = {("main", 1, 100.0 * k): float(x) for k, x in enumerate(rng.uniform(1.0, 4.0, 8))}
    keys = list(segs)
    driven = {"v0": keys[:5], "v1": keys[2:7], "v2": keys[4:], "v3": keys[:3], "v4": keys[5:], "v5": keys[1:4]}
    out = calibrate_gains(_obs(g, segs, driven))
    mean = math.exp(np.mean([math.log(x) for x in g.values()]))
    for v, gv in g.items():
        assert out[v].gain == pytest.approx(gv / mean, rel=1e-12)
        assert out[v].status == "calibrated" and out[v].component == 0
        assert out[v].gain_high - out[v].gain_low < 1e-9                  # no residual: a zero-width interval
    assert out["v0"].n_segments == 5 and out["v0"].n_peers == 4          # v1, v2, v3, v5 (not v4)


def test_a_reference_vehicle_anchors_its_component_and_the_absolute_level_is_exact():
    g = {"ref": 1.0, "a": 1.25, "b": 0.8, "c": 1.1}
    segs = {k: 1.0 + 0.5 * k for k in range(4)}
    driven = {"ref": [0, 1], "a": [0, 1, 2], "b": [2, 3], "c": [1, 3]}
    out = calibrate_gains(_obs(g, segs, driven), reference=["ref"])
    assert {v: round(r.gain, 12) for v, r in out.items()} == g
    assert out["ref"].status == "reference" and out["a"].status == "calibrated"


def test_components_are_normalised_separately_and_a_vehicle_alone_keeps_gain_1():
    g = {"a": 1.2, "b": 0.9, "c": 1.5, "d": 1.0 / 1.5, "e": 1.3}
    driven = {"a": [0, 1], "b": [0, 1], "c": [5, 6], "d": [5, 6], "e": [9, 10]}
    out = calibrate_gains(_obs(g, dict.fromkeys(range(11), 2.0), driven))
    assert out["a"].component != out["c"].component
    assert out["a"].gain == pytest.approx(math.sqrt(1.2 / 0.9), rel=1e-12)      # geometric mean of a, b is 1
    assert out["c"].gain == pytest.approx(1.5, rel=1e-12)
    assert out["e"].gain == 1.0 and out["e"].status == "uncalibrated" and math.isnan(out["e"].gain_low)


def test_noisy_gains_are_within_their_interval_and_bad_values_are_left_out():
    rng = np.random.default_rng(7)
    g = {f"v{i}": float(x) for i, x in enumerate(np.exp(rng.normal(0.0, 0.15, 8)))}
    segs = {k: float(x) for k, x in enumerate(rng.uniform(1.0, 4.0, 30))}
    driven = {v: list(rng.choice(30, 12, replace=False)) for v in g}
    obs = _obs(g, segs, driven, noise=rng) + [("v0", 99, float("nan")), ("v0", 98, -1.0)]
    out = calibrate_gains(obs)
    mean = math.exp(np.mean([math.log(x) for x in g.values()]))
    inside = sum(out[v].gain_low <= gv / mean <= out[v].gain_high for v, gv in g.items())
    assert inside >= 6
    assert max(abs(out[v].gain / (gv / mean) - 1) for v, gv in g.items()) < 0.05


def test_vehicle_id_round_trips_and_a_bad_one_is_named(tmp_path):
    from roadcollab.errors import FileFormatError
    from roadcollab.io.drive_params import read_drive_params, write_drive_params
    from roadcollab.models.vehicle import HalfCarParameters

    for suffix in (".toml", ".json"):
        p = write_drive_params(tmp_path / f"d{suffix}", speed=15.0, params=HalfCarParameters(), vehicle_id="van-07")
        assert read_drive_params(p)["vehicle_id"] == "van-07"
        assert read_drive_params(write_drive_params(tmp_path / f"e{suffix}", speed=15.0,
                                                    params=HalfCarParameters()))["vehicle_id"] is None
    bad = write_drive_params(tmp_path / "bad.toml", speed=15.0, params=HalfCarParameters(), vehicle_id="van 07/")
    with pytest.raises(FileFormatError, match=r"bad.toml: key 'vehicle_id' must be 1-64 letters"):
        read_drive_params(bad)


def test_a_reference_vehicle_needs_calibrate_and_a_drive_of_its_own():
    from roadcollab.errors import ParameterError
    from roadcollab.experiments.drives.road_survey import survey_drives

    with pytest.raises(ParameterError, match="--reference-vehicle needs --calibrate"):
        survey_drives([], None, reference=["van-07"])
    with pytest.raises(ParameterError, match="--reference-vehicle 'van-07': no drive's parameters file"):
        survey_drives([], None, calibrate=True, reference=["van-07"])
