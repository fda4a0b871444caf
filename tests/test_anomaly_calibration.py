"""Tests of roadcollab.experiments.anomalies.calibration and ``roadcollab calibrate-anomalies``."""

from __future__ import annotations

import csv
import json
import re

import numpy as np
import pytest

from roadcollab.detection.detector import DetectorSpec
from roadcollab.experiments.anomalies.calibration import calibrate_anomalies
from roadcollab.experiments.anomalies.config import ESTIMATORS, AnomalyStudyConfig
from roadcollab.experiments.anomalies.study import run_anomaly_study
from roadcollab.experiments.anomalies.calibration_config import EVALUATION_SEEDS, AnomalyCalibrationConfig, parse_seeds
from roadcollab.cli.main import build_parser, main
from roadcollab.errors import ParameterError
from roadcollab.experiments.config import ExperimentConfig

# 1 seed, 2 runs, 3 vehicles, a 2 x 2 grid whose thresholds are far apart (different objectives).
TINY = ["--seeds", "1000", "--runs-per-seed", "2", "--vehicles", "3", "--snr-thresholds", "3.5", "4.5",
        "--min-depths-mm", "7.5", "12.5"]
CONDITIONS = ("default", "all_20mm", "all_30mm")


def _read_csv(path):
    """Rows of a CSV as dicts, the file closed again (no ResourceWarning)."""
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def read_rows(out):
    return _read_csv(out / "calibration.csv")


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("cal") / "tiny"
    assert main(["calibrate-anomalies", "--out", str(out), *TINY]) == 0
    return out


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_csv_has_one_row_per_grid_point_and_every_column(tiny):
    rows = read_rows(tiny)
    expected = ["snr_threshold", "min_depth_m", "objective", "gap_to_best", "gap_se"] + [
        f"{m}_{c}_{e}" for m in ("f1", "precision", "recall") for c in CONDITIONS for e in ESTIMATORS]
    assert list(rows[0].keys()) == expected
    assert [(float(r["snr_threshold"]), float(r["min_depth_m"])) for r in rows] == [
        (3.5, 0.0075), (3.5, 0.0125), (4.5, 0.0075), (4.5, 0.0125)]
    for r in rows:
        for col in expected[2:4] + expected[5:]:
            assert 0.0 <= float(r[col]) <= 1.0, col
        assert r["gap_se"] == "nan"   # one seed: no spread over seeds


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_objective_is_mean_f1_of_collaborative_and_fused_over_conditions(tiny):
    for r in read_rows(tiny):
        f1 = [float(r[f"f1_{c}_{e}"]) for c in CONDITIONS for e in ("collaborative", "fused")]
        assert float(r["objective"]) == pytest.approx(np.mean(f1), rel=1e-12)


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_reported_best_point_is_the_argmax_of_the_objective(tiny):
    rows = read_rows(tiny)
    objective = [float(r["objective"]) for r in rows]
    assert len(set(objective)) > 1, "the grid must discriminate for this test to mean anything"
    k = int(np.argmax(objective))
    m = re.search(r"Best point: snr_threshold = ([0-9.]+), min_depth = ([0-9.]+) m", (tiny / "report.md").read_text())
    assert m, "report.md must state the best point"
    assert (float(m.group(1)), float(m.group(2))) == (float(rows[k]["snr_threshold"]), float(rows[k]["min_depth_m"]))
    for r, obj in zip(rows, objective):
        assert float(r["gap_to_best"]) == pytest.approx(max(objective) - obj, abs=1e-15)


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_config_json_records_seeds_configuration_and_version(tiny):
    cfg = json.loads((tiny / "config.json").read_text())
    assert cfg["seeds"] == [1000] and cfg["config"]["seeds"] == [1000]
    assert cfg["config"]["runs_per_seed"] == 2 and cfg["config"]["experiment"]["n_vehicles"] == 3
    assert cfg["config"]["snr_thresholds"] == [3.5, 4.5] and cfg["config"]["min_depths"] == [0.0075, 0.0125]
    assert cfg["roadcollab_version"] and "calibrate-anomalies" in cfg["command"]


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_scores_equal_the_anomaly_study_on_the_same_seed_and_runs(tiny):
    """Training seed s with R runs is the anomaly study with root seed s and n_runs = R: its default
    condition and its 2 cm / 3 cm depth sweep must give exactly the calibration's scores."""
    row = read_rows(tiny)[3]   # (4.5, 12.5 mm)
    cfg = AnomalyStudyConfig(experiment=ExperimentConfig(n_vehicles=3, n_runs=1), n_runs=2, depths=(0.02, 0.03),
                             noise_levels=(), detector=DetectorSpec(snr_threshold=4.5, min_depth=0.0125))
    study = run_anomaly_study(cfg, 1000)
    by_condition = {"default": study.detection_rows,
                    "all_20mm": [r for r in study.depth_rows if r.depth_m == 0.02],
                    "all_30mm": [r for r in study.depth_rows if r.depth_m == 0.03]}
    for c, rows in by_condition.items():
        assert [r.estimator for r in rows] == list(ESTIMATORS)
        for r in rows:
            for m in ("f1", "precision", "recall"):
                assert float(row[f"{m}_{c}_{r.estimator}"]) == pytest.approx(getattr(r, m), rel=1e-12), (c, m)


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_same_arguments_give_identical_files(tiny, tmp_path):
    again = tmp_path / "again"
    assert main(["calibrate-anomalies", "--out", str(again), *TINY]) == 0
    assert (again / "calibration.csv").read_bytes() == (tiny / "calibration.csv").read_bytes()


def test_evaluation_seed_is_refused(tmp_path, capsys):
    out = tmp_path / "refused"
    args = ["--seeds", "0-2"] + TINY[2:]
    assert main(["calibrate-anomalies", "--out", str(out), *args]) == 2
    err = capsys.readouterr().err
    assert "roadcollab calibrate-anomalies: error: seeds must be training seeds" in err and "[0]" in err
    assert not out.exists()
    with pytest.raises(ParameterError, match=r"seeds must be training seeds, not evaluation seeds \[0\].*got \[0\]"):
        AnomalyCalibrationConfig(seeds=(1000, 0))


def test_evaluation_seeds_include_the_default_seed_of_the_anomaly_study():
    assert build_parser().parse_args(["anomalies", "--out", "x"]).seed in EVALUATION_SEEDS


def test_parse_seeds_ranges_and_errors():
    assert parse_seeds(["1000-1002", "7"]) == (1000, 1001, 1002, 7)
    assert parse_seeds("5,9-10") == (5, 9, 10)
    for bad, msg in (("5-3", "ascending"), ("x", "integers"), ("-1", "integers"), ("1.5", "integers"),
                     ([], "at least one")):
        with pytest.raises(ParameterError, match=msg):
            parse_seeds(bad)


@pytest.mark.parametrize("kw, msg", [
    ({"seeds": (1000, 1000)}, "seeds must be distinct"),
    ({"runs_per_seed": 0}, "runs_per_seed must be >= 1"),
    ({"snr_thresholds": ()}, "snr_thresholds must be a non-empty"),
    ({"min_depths": (0.01, -0.01)}, r"min_depths\[1\] must be >= 0"),
    ({"condition_depths": (0.02, 0.02)}, "condition_depths must not repeat"),
    ({"experiment": ExperimentConfig(n_vehicles=1)}, "experiment.n_vehicles must be >= 2"),
])
def test_config_rejects_bad_values_naming_the_parameter(kw, msg):
    with pytest.raises(ParameterError, match=msg):
        AnomalyCalibrationConfig(**kw)


def test_seeds_are_pooled_per_seed_and_dask_gives_identical_results():
    """Two seeds of two runs: each seed's objective equals a one-seed calibration's, and the pooled
    result does not depend on running serially or on two Dask workers."""
    common = dict(runs_per_seed=2, experiment=ExperimentConfig(n_vehicles=3, n_runs=1), snr_thresholds=(3.5, 4.5),
                  min_depths=(0.0125,))
    both = calibrate_anomalies(AnomalyCalibrationConfig(seeds=(1001, 1002), **common))
    for k, s in enumerate((1001, 1002)):
        one = calibrate_anomalies(AnomalyCalibrationConfig(seeds=(s,), **common))
        assert [p.seed_objectives[k] for p in both.points] == [p.objective for p in one.points]
    dask = calibrate_anomalies(AnomalyCalibrationConfig(seeds=(1001, 1002), **common), workers=2)
    values = lambda res: np.array([list(r.record().values()) for r in res.to_rows()], dtype=float)  # noqa: E731
    np.testing.assert_array_equal(values(dask), values(both))
    assert [list(r.record()) for r in both.to_rows()] == [both.columns()] * 2   # the columns, in order
