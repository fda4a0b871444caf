"""The receiver guard on the recorded-drive path (issue 20, section 4): ``roadcollab estimate`` and the
networked vehicle apply a received message only through a guard built from the drive's own priors."""

import json

import numpy as np
import pytest

import roadcollab as rc
from roadcollab.cli.main import main
from roadcollab.collaboration.drive_guard import drive_fleet_prior, iso_road_moment, own_road_moment
from roadcollab.errors import ParameterError
from roadcollab.experiments.security.drive_receiver import drive_receiver_rows, honest_refusals, time_grid_rows
from roadcollab.experiments.drives.simulation import simulate_drives, write_drives
from roadcollab.experiments.drives.fleet_estimation import estimate_fleet, invert_drive
from roadcollab.network.engine import VehicleEngine
from roadcollab.network.plan import RoadPlan


@pytest.fixture(scope="module")
def sim():
    return simulate_drives(vehicles=2, seed=0)


def test_drive_prior_is_the_stated_accuracy_around_the_estimate(sim):
    p = sim.drives[0].drive.params
    spec = drive_fleet_prior(p, 0.05)
    assert spec.nominal is p and spec.spread == pytest.approx(0.15) and spec.estimate_uncertainty == 0.05
    with pytest.raises(ParameterError, match="uncertainty"):
        drive_fleet_prior(p, 0.5)


def test_class_road_moment_is_the_design_road():
    """The white-in-time moment of the ISO class agrees with the simulated class C road's (FleetPipeline's
    road draws, with anomalies and tyre enveloping) within a factor 2.5 per octave band, 0.5-20 Hz."""
    cfg = rc.ExperimentConfig(n_vehicles=1)
    pipe = rc.FleetPipeline(cfg, rc.sample_fleet(1, cfg.fleet, rng=1))
    car = pipe.estimators[0]
    S_iso, S = iso_road_moment(car, cfg.noise_model()), pipe.road_moment
    f = car.grid.freqs[car.grid.active]

    def tr(A):
        return np.real(A[:, 0, 0] + A[:, 1, 1])

    for lo in (0.5, 1, 2, 4, 8, 16):
        m = (f >= lo) & (f < min(2 * lo, 20))
        assert 0.4 < tr(S)[m].mean() / tr(S_iso)[m].mean() < 2.5, lo
    own = own_road_moment(car, [car.grid.rfft(np.zeros((cfg.n_samples, 2)))])
    assert own.shape == S.shape and not own.any()


def test_recorded_drive_path_is_guarded_by_default(sim):
    d = sim.drives[1].drive
    assert invert_drive(d, gamma=512.0, band_low_hz=0.5).guard is not None
    assert invert_drive(d, gamma=512.0, band_low_hz=0.5, guard=None).guard is None
    plan = RoadPlan(min_speed=float(d.speeds().min()))
    assert VehicleEngine(d, plan, index=1).rec.guard.estimator.guard is not None
    assert VehicleEngine(d, plan, index=1, guard=None).rec.guard is None
    with pytest.raises(ParameterError, match="road must be"):
        invert_drive(d, gamma=512.0, band_low_hz=0.5, guard="mud")


def test_guard_changes_the_distance_path_and_is_recorded(sim):
    drives = [s.drive for s in sim.drives]
    guarded, plain = estimate_fleet(drives), estimate_fleet(drives, guard=None)
    assert guarded.receiver_guard == "class" and plain.receiver_guard == "none"
    g, p = guarded.elevation["collaborative"][1], plain.elevation["collaborative"][1]
    ok = np.isfinite(g[:, 0])
    assert not np.allclose(g[ok], p[ok])                       # the guard is on this path
    assert np.array_equal(guarded.elevation["inversion"], plain.elevation["inversion"], equal_nan=True)


def test_time_grid_path_rows():
    """The receiver rows through ``estimate_drives`` (drives on one time grid), drive priors only."""
    rows = {(r.attack, r.guard): r for g in ("class", None) for r in time_grid_rows((0,), guard=g)}
    assert rows["scale_1e6", "none"].ratio > 1e6                # what the opt-out lets through
    for attack in ("honest", "scale_1e6", "coherent_up", "coherent_down", "fake_pothole_09", "fake_pothole_full"):
        r = rows[attack, "class"]
        assert r.ratio <= 2.0 and r.fakes == 0, r
    assert rows["honest", "class"].refused_bands == 0
    assert rows["fake_pothole_full", "none"].fakes >= 1          # the full pothole is planted unguarded


@pytest.mark.slow
def test_distance_path_rows_and_honest_refusals():
    rows = {(r.attack, r.seed): r for r in drive_receiver_rows((0, 1), guard="class")}
    assert all(r.ratio <= 2.0 and r.fakes == 0 for r in rows.values()), rows
    refused, bands, whole, messages = honest_refusals((0,), vehicles=5)
    assert whole == 0 and refused <= 0.15 * bands


def _cli_records(tmp_path, sim, cases):
    (tmp_path / "drives").mkdir()
    paths = write_drives(sim, tmp_path / "drives")
    for extra, want in cases:
        out = tmp_path / f"out{len(extra)}{want}"
        assert main(["estimate", *[a for p in paths for a in ("--drive", str(p))],
                     "--out", str(out), *extra]) == 0
        config = json.loads((out / "config.json").read_text())
        assert config["config"]["receiver_guard"] == want
        assert ("--unguarded-receive" in config["command"]) == (want == "none")


def test_cli_records_the_opt_out(tmp_path, sim):
    _cli_records(tmp_path, sim, [(["--unguarded-receive"], "none")])


@pytest.mark.slow
def test_cli_records_the_guard(tmp_path, sim):
    _cli_records(tmp_path, sim, [([], "class"), (["--guard-road", "own"], "own")])
