"""Fleets at different speeds on one distance grid, start offsets, and messy logs (issue 10, sections 1-2)."""

import csv
import re

import numpy as np
import pytest

from roadcollab import ParameterError
from roadcollab.cli.estimate import estimate_command
from roadcollab.experiments.drives.mixed_fleet import MIXED_SPEEDS, MixedFleetRow, mixed_fleet_check, simulate_drive
from roadcollab.io.drive_params import write_drive_params
from roadcollab.io.drives import load_drive, write_drive_csv
from roadcollab.io.profiles import measured_road
from roadcollab.models.vehicle import FleetSpec, HalfCarParameters, sample_fleet

PARAMS = HalfCarParameters(700.0, 500.0, 0.7, 0.8, 20000.0, 1500.0)


@pytest.fixture(scope="module")
def mixed():
    return mixed_fleet_check(MIXED_SPEEDS, seed=0)


def test_mixed_fleet_meets_the_done_when(mixed):
    """12, 15, 18 and 13-17 m/s over the measured profile: fused NMSE <= 0.02 and <= half the single mean."""
    assert mixed.speeds == (12.0, 15.0, 18.0, (13.0, 17.0))
    assert mixed.fused <= 0.02
    assert mixed.fused <= 0.5 * mixed.single_mean
    # Fusion keeps improving down the fleet (running average of the inversions).
    assert mixed.nmse["fused"][-1] < mixed.nmse["fused"][0]


def test_mixed_fleet_rows_are_typed_per_drive(mixed):
    rows = mixed.to_rows()
    assert [type(r) for r in rows] == [MixedFleetRow] * 4
    assert [(r.drive, r.speed) for r in rows] == [(1, "12"), (2, "15"), (3, "18"), (4, "13-17")]
    for name in ("single", "inversion", "collaborative", "fused"):
        np.testing.assert_array_equal([getattr(r, name) for r in rows], mixed.nmse[name])


def test_mixed_speeds_as_accurate_as_one_speed(mixed):
    same = mixed_fleet_check((15.0,) * 4, seed=0)
    assert mixed.fused <= 1.5 * same.fused
    # Vehicle by vehicle (same vehicles, same noise), its own inversion is as good at its own speed.
    assert np.all(mixed.nmse["inversion"] <= 1.5 * same.nmse["inversion"])


def test_oracle_mapping_through_distance_is_nearly_exact():
    """With noise-free sensors and the vehicles' true parameters, the time -> distance map loses little."""
    road = measured_road(rng=1)
    fleet = sample_fleet(2, FleetSpec(estimate_uncertainty=0.0), rng=2)
    from roadcollab.experiments.drives.fleet_estimation import estimate_fleet
    from roadcollab.experiments.drives.mixed_fleet import score_fleet
    drives = [simulate_drive(road, fleet[0], 12.0, start=5.0, noise_std=0.0, rng=3),
              simulate_drive(road, fleet[1], (13.0, 17.0), start=9.0, noise_std=0.0, rng=4)]
    nmse = score_fleet(estimate_fleet(drives), road)
    assert np.all(nmse["inversion"] < 2e-3)


@pytest.mark.slow  # 10 s end to end
def test_start_offsets_are_estimated():
    errors = (2.5, -3.0, 1.2, 3.0)
    aligned = mixed_fleet_check(MIXED_SPEEDS, seed=1, start_errors=errors, align=True)
    assert np.max(np.abs(aligned.offset_errors)) < 0.15
    assert aligned.fused <= 0.02
    raw = mixed_fleet_check(MIXED_SPEEDS, seed=1, start_errors=errors, align=False)
    assert raw.fused > 5 * aligned.fused


# --- messy logs ----------------------------------------------------------------------------------

def _signal(t):
    return np.column_stack([np.sin(2 * np.pi * 2.0 * t), 0.5 * np.cos(2 * np.pi * 11.0 * t)])


def test_jittery_time_stamps_are_resampled(tmp_path):
    rng = np.random.default_rng(0)
    fs, n = 200.0, 2000
    t = 3.0 + (np.arange(n) + rng.uniform(-0.04, 0.04, n)) / fs       # +-4 % jitter
    write_drive_csv(tmp_path / "d.csv", t, _signal(t))
    write_drive_params(tmp_path / "d.toml", speed=15.0, params=PARAMS)
    d = load_drive(tmp_path / "d.csv")
    assert d.resampled and 0.03 < d.max_jitter < 0.09
    assert abs(d.sample_rate - fs) < 0.01 * fs
    assert np.allclose(np.diff(d.time), 1 / d.sample_rate)
    inner = slice(5, -5)
    err = d.accel[inner] - _signal(d.time)[inner]
    assert np.max(np.abs(err)) < 2e-3


def test_rate_too_low_for_the_suspension(tmp_path):
    t = np.arange(200) / 15.0
    write_drive_csv(tmp_path / "d.csv", t, _signal(t))
    write_drive_params(tmp_path / "d.toml", speed=15.0, params=PARAMS)
    with pytest.raises(ParameterError, match="^" + re.escape(str(tmp_path / "d.csv")) + r": expected a sample rate of "
                       r"at least 20 Hz \(the larger of 20 Hz and 10x the highest body mode, 1.\d+ Hz, of the vehicle "
                       r"in d.toml\), got 15 Hz"):
        load_drive(tmp_path / "d.csv")
    # Roll mode sqrt(2 k_s (L1^2 + L2^2) / I_x) / 2 pi = sqrt(2 * 2e5 * 1.62 / 100) / 2 pi = 12.8 Hz.
    stiff = HalfCarParameters(700.0, 100.0, 0.9, 0.9, 200000.0, 1500.0)
    t = np.arange(400) / 50.0
    write_drive_csv(tmp_path / "e.csv", t, _signal(t))
    write_drive_params(tmp_path / "e.toml", speed=15.0, params=stiff)
    with pytest.raises(ParameterError, match=r"expected a sample rate of at least 128.1 Hz .*body mode, 12.8 Hz, .* got 50 Hz"):
        load_drive(tmp_path / "e.csv")


def test_speed_and_distance_columns(tmp_path):
    t = np.arange(400) / 100.0
    v = 10.0 + t
    write_drive_csv(tmp_path / "s.csv", t, _signal(t), column="speed_mps", values=v)
    write_drive_params(tmp_path / "s.toml", speed=None, params=PARAMS, start_m=7.0)
    d = load_drive(tmp_path / "s.csv")
    assert d.speed_source == "speed_mps column" and not d.constant_speed
    assert np.allclose(d.positions, 7.0 + 10.0 * t + 0.5 * t ** 2)      # trapezoid exact for a linear speed
    write_drive_csv(tmp_path / "x.csv", t, _signal(t), column="distance_m", values=100.0 + 12.0 * t)
    write_drive_params(tmp_path / "x.json", speed=None, params=PARAMS, start_m=3.0)
    x = load_drive(tmp_path / "x.csv")
    assert np.allclose(x.positions, 3.0 + 12.0 * t) and abs(x.speed - 12.0) < 1e-9
    write_drive_params(tmp_path / "s.toml", speed=15.0, params=PARAMS)
    with pytest.raises(ParameterError, match="^" + re.escape(str(tmp_path / "s.toml")) + ": key 'speed_mps' must be "
                       "absent: the drive's CSV carries a speed_mps column"):
        load_drive(tmp_path / "s.csv")


# --- the command on files ------------------------------------------------------------------------

def test_estimate_command_on_distance(tmp_path):
    road = measured_road(rng=5)
    fleet = sample_fleet(2, FleetSpec(), rng=6)
    paths = []
    for j, (speed, start, given) in enumerate(((12.0, 6.0, 8.0), ((13.0, 17.0), 40.0, 39.0))):
        d = simulate_drive(road, fleet[j], speed, start=start, given_start=given, rng=j)
        column = None if j == 0 else "speed_mps"
        values = None if j == 0 else d.speeds()
        paths.append(write_drive_csv(tmp_path / f"d{j + 1}.csv", d.time, d.accel, column=column, values=values))
        write_drive_params(tmp_path / f"d{j + 1}.toml", speed=speed if j == 0 else None, params=d.params,
                           start_m=given)
    out = tmp_path / "out"
    summary = estimate_command([str(p) for p in paths], out, command="x", align=True, segment_length=100.0)
    assert summary["grid"] == "distance"
    for name in summary["files"]:
        assert (out / name).stat().st_size > 0, name
    # True relative offset: drive 1 was recorded 2 m too far, drive 2 1 m too short: corrections -1.5, +1.5.
    assert np.allclose(summary["offsets_m"], [-1.5, 1.5], atol=0.15)
    with (out / "final_estimate.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0])[:4] == ["position_m", "elevation_fused_left", "elevation_fused_right", "coverage"]
    with (out / "road_estimates.csv").open() as fh:
        est = list(csv.DictReader(fh))
    first = next(r for r in est if r["elevation_inversion_v1_left"] != "")     # drive 1 starts 32 m before drive 2
    assert first["elevation_single_v2_left"] == "" and first["elevation_fused_v2_left"] != ""
    assert est[0]["elevation_fused_v2_left"] == ""                               # the grid is padded by --max-offset
    with (out / "iri.csv").open() as fh:
        iri = list(csv.DictReader(fh))
    assert len(iri) >= 4 and all(0.3 < float(r["iri_m_per_km"]) < 20 for r in iri)
    assert "## IRI of the fused elevation" in (out / "report.md").read_text()
