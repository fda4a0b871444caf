"""``roadcollab sweep``: the gamma x noise x uncertainty grid, its CSV, report and seeds."""

import csv
import json
import math
import re

import numpy as np
import pytest

from roadcollab import ExperimentConfig, ParameterError
from roadcollab.cli.main import main
from roadcollab.experiments.sweep.study import run_sweep
from roadcollab.experiments.sweep.config import SWEPT_ESTIMATORS, SweepConfig
from roadcollab.experiments.sweep.findings import ratio_of_means
from roadcollab.experiments.sweep.result import SweepResult, SweepRow
from roadcollab.reporting.records import row_columns
from roadcollab.reporting.sweep_report import write_sweep

FIRST_COLUMNS = ["gamma", "sensor_noise_std", "parameter_uncertainty", "vehicle1_observer_mse", "algorithm1_mse",
                 "own_inversion_mse", "fused_mse", "oracle_per_bin_mse"]
TINY = ["--vehicles", "3", "--runs", "2", "--gammas", "1,128", "--noise", "0.05", "--uncertainty", "0.1"]
TINY_CONFIG = SweepConfig(gammas=(1, 128), sensor_noise_stds=(0.05,), parameter_uncertainties=(0.1,), n_vehicles=3,
                          n_runs=2)


def _read_csv(path):
    with path.open() as fh:
        reader = csv.DictReader(fh)
        return reader.fieldnames, list(reader)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep")
    assert main(["sweep", "--out", str(out), "--seed", "3", *TINY]) == 0
    return out


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_cli_writes_csv_figure_config_and_report(tiny):
    columns, rows = _read_csv(tiny / "sweep.csv")
    assert columns[:len(FIRST_COLUMNS)] == FIRST_COLUMNS
    for extra in ("observer_only_mse", "centralized_mse", "algorithm1_gain", "algorithm1_mse_se",
                  "algorithm1_gain_se", "n_runs"):
        assert extra in columns[len(FIRST_COLUMNS):]
    assert [float(r["gamma"]) for r in rows] == [1.0, 128.0]
    for r in rows:
        for c in columns:
            v = float(r[c])
            assert math.isfinite(v) and v > 0, (c, v)
        assert int(r["n_runs"]) == 2
    assert (tiny / "sweep.png").stat().st_size > 10_000
    cfg = json.loads((tiny / "config.json").read_text())
    assert cfg["seed"] == 3 and "roadcollab_version" in cfg
    assert cfg["config"]["gammas"] == [1.0, 128.0] and cfg["config"]["n_vehicles"] == 3
    assert "gamma" not in cfg["config"]["experiment"]  # swept: recorded in the grid, not as a single value
    report = (tiny / "report.md").read_text()
    assert "![MSE vs gamma](sweep.png)" in report


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_oracle_per_bin_is_below_own_inversion_and_weak_observer_is_worse(tiny):
    _, rows = _read_csv(tiny / "sweep.csv")
    for r in rows:
        assert float(r["oracle_per_bin_mse"]) < float(r["own_inversion_mse"])
    weak, strong = (float(r["vehicle1_observer_mse"]) for r in rows)  # gamma 1, gamma 128
    assert weak > 5 * strong


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_report_states_the_measured_ratio(tiny):
    _, rows = _read_csv(tiny / "sweep.csv")
    strong = rows[-1]
    ratio = float(strong["algorithm1_mse"]) / float(strong["vehicle1_observer_mse"])
    assert f"Algorithm 1 / observer = {ratio:.3g}" in (tiny / "report.md").read_text()


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_same_seed_reproduces_the_csv_and_another_seed_differs(tiny):
    """The library with the command's seed and kernel path (config.json says which: the command's default is the
    compiled path, the library's the numpy one; the two agree to round-off, not bit for bit) gives its CSV."""
    from roadcollab.lti.kernels import use_kernels

    _, rows = _read_csv(tiny / "sweep.csv")
    with use_kernels(json.loads((tiny / "config.json").read_text())["kernels"]):
        again = run_sweep(TINY_CONFIG, 3).to_rows()
    assert [{k: float(r[k]) for k in r} for r in rows] == [{k: float(getattr(r, k)) for k in row_columns(SweepRow)}
                                                           for r in again]
    other = run_sweep(TINY_CONFIG, 4).to_rows()
    assert all(a.algorithm1_mse != b.algorithm1_mse for a, b in zip(again, other))


def test_common_random_numbers_across_gammas():
    # Estimators that do not use the observer see the same road, noise and fleet at every gamma.
    res = run_sweep(SweepConfig(gammas=(2, 64), sensor_noise_stds=(0.1,), parameter_uncertainties=(0.05,),
                                n_vehicles=2, n_runs=2, experiment=ExperimentConfig(segment_length=90.0)), 5)
    for name in ("own_inversion", "fused", "centralized", "oracle_per_bin"):
        np.testing.assert_allclose(res.mse[name][0], res.mse[name][1], rtol=1e-12, err_msg=name)
    assert not np.allclose(res.mse["observer_only"][0], res.mse["observer_only"][1])


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_dask_matches_serial():
    cfg = SweepConfig(gammas=(8,), sensor_noise_stds=(0.05,), parameter_uncertainties=(0.1,), n_vehicles=2, n_runs=3,
                      experiment=ExperimentConfig(segment_length=90.0))
    assert run_sweep(cfg, 1).to_rows() == run_sweep(cfg, 1, workers=2).to_rows()


def test_ratio_of_means_by_hand():
    # a = [1, 3], b = [1, 1]: G = 2, residuals a - G b = [-1, 1], SE = sqrt(2 / (2 * 1)) / 1 = 1.
    assert ratio_of_means([1.0, 3.0], [1.0, 1.0]) == (2.0, 1.0)
    g, se = ratio_of_means([2.0], [4.0])
    assert g == 0.5 and math.isnan(se)


def _hand_result(alg1_strong: float) -> SweepResult:
    """V = 3, R = 2, gammas (1, 100): observer at vehicle 1 is 8 then 1; Algorithm 1 is 1 then ``alg1_strong``."""
    cfg = SweepConfig(gammas=(1, 100), sensor_noise_stds=(0.05,), parameter_uncertainties=(0.1,), n_vehicles=3,
                      n_runs=2)
    mse = {k: np.ones((2, 2, 3)) for k in SWEPT_ESTIMATORS}
    mse["observer_only"][0, :, 0] = [6.0, 10.0]          # mean 8 at gamma 1
    mse["algorithm1"][0, :, 1:] = [[0.5, 1.5], [1.0, 1.0]]  # per-run means 1, 1
    mse["algorithm1"][1, :, 1:] = alg1_strong
    mse["own_inversion"][:] = 2.0
    mse["oracle_per_bin"][:, :, 2] = 0.1
    mse["fused"][:, :, 2] = 0.3
    return SweepResult(config=cfg, seed=0, mse=mse)


def test_table_and_findings_by_hand(tmp_path):
    res = _hand_result(0.9)
    weak, strong = res.table()
    assert (weak.vehicle1_observer_mse, weak.algorithm1_mse, weak.algorithm1_gain) == (8.0, 1.0, 8.0)
    # gain SE: residuals a - 8 b = [-2, 2] -> sqrt(8 / 2) / 1 = 2; algorithm1 per-run means [1, 1] -> SE 0.
    assert weak.algorithm1_gain_se == 2.0 and weak.algorithm1_mse_se == 0.0
    assert (weak.own_inversion_mse, weak.oracle_per_bin_mse, weak.fused_mse) == (2.0, 0.1, 0.3)
    assert strong.algorithm1_gain == pytest.approx(1 / 0.9)
    (f,) = res.findings()
    assert f.smallest_gamma_within == 100.0 and f.gammas_algorithm1_wins == (1.0,)
    assert f.wins_only_for_weak_observers and f.algorithm1_over_observer_at_largest == pytest.approx(0.9)
    # Same vehicles 2..V: Algorithm 1 0.9 vs own inversion 2.0 in both runs; every gain is resolved (SE 2 and 0).
    assert f.algorithm1_over_own_inversion_at_largest == pytest.approx(0.45)
    assert f.algorithm1_over_own_inversion_at_largest_se == 0.0 and f.unresolved_gammas == ()
    write_sweep(res, tmp_path / "weak", command="test", elapsed=0.0)
    assert "only for weak observers" in (tmp_path / "weak" / "report.md").read_text()
    # Algorithm 1 four times better at the strong observer too: the report must say so instead.
    g = _hand_result(0.25).findings()[0]
    assert g.smallest_gamma_within is None and not g.wins_only_for_weak_observers
    write_sweep(_hand_result(0.25), tmp_path / "strong", command="test", elapsed=0.0)
    text = (tmp_path / "strong" / "report.md").read_text()
    assert "only for weak observers" not in text and "including at the strongest swept observer" in text


@pytest.mark.parametrize("kwargs, message", [
    ({"gammas": (1.0, -1.0)}, r"gammas\[1\] must be > 0, got -1"),
    ({"sensor_noise_stds": (-0.1,)}, r"sensor_noise_stds\[0\] must be >= 0, got -0.1"),
    ({"parameter_uncertainties": (0.5,)}, r"parameter_uncertainties\[0\] must be <= 0.3, got 0.5"),
    ({"gammas": ()}, "gammas must hold at least one value, got none"),
    ({"gammas": (8.0, 8.0)}, "gammas must not repeat a value"),
    ({"n_vehicles": 1}, "n_vehicles must be >= 2, got 1"),
    ({"n_runs": 0}, "n_runs must be >= 1, got 0"),
])
def test_bad_config_names_the_parameter(kwargs, message):
    with pytest.raises(ParameterError, match=message) as info:
        SweepConfig(**kwargs)
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize("args, message", [
    (["--gammas", "1,x"], r"argument --gammas: expected an observer gamma from 0.01 to 10,000, got 'x' \(not a number\)"),
    (["--gammas", "1,-8"], r"argument --gammas: expected an observer gamma from 0.01 to 10,000, got -8"),
    (["--vehicles", "1"], r"argument --vehicles: expected a fleet size from 2 to 1,000, got 1"),
])
def test_cli_rejects_bad_input_cleanly(tmp_path, capsys, args, message):
    # Refused while parsing (issue 18: every numeric option has a range), with argparse's status 2.
    with pytest.raises(SystemExit) as exc:
        main(["sweep", "--out", str(tmp_path), "--runs", "1", *args])
    assert exc.value.code == 2
    assert re.search(message, capsys.readouterr().err)
