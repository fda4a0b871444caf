"""The command-line interface writes every promised output and fails cleanly on bad input."""

import csv
import json
from pathlib import Path

import pytest

from roadcollab.experiments.reproduction.rows import IriRow
from roadcollab.reporting.records import row_columns
from roadcollab.wire import protocol
from roadcollab.cli.main import main

README = Path(__file__).resolve().parents[1] / "README.md"


def _read_csv(path):
    """Rows of a CSV as dicts, the file closed again (no ResourceWarning)."""
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_reproduce_writes_all_outputs(tmp_path):
    out = tmp_path / "rep"
    assert main(["reproduce", "--runs", "2", "--vehicles", "3", "--seed", "4", "--measured-runs", "2",
                 "--out", str(out)]) == 0
    for name in ("mse.csv", "fig4_mse.png", "fig5_vehicle1.png", "fig6_vehicle2.png", "fig7_vehicle3.png",
                 "fig5_vehicle1.csv", "fig_fusion.png", "fleet.csv", "config.json", "report.md",
                 "mse_measured.csv", "fig_measured_mse.png", "iri_measured.csv", "fig_fusion.csv"):
        assert (out / name).stat().st_size > 0, name
    iri_rows = _read_csv(out / "iri_measured.csv")
    assert list(iri_rows[0]) == row_columns(IriRow) and len(iri_rows) == 2 * 2 * 6  # runs x tracks x 50 m segments
    assert "estimated against true IRI" in (out / "report.md").read_text()
    rows = _read_csv(out / "mse.csv")
    assert [r["vehicle"] for r in rows] == ["1", "2", "3"]
    for col in ("vehicle", "mse_mean", "mse_std", "mse_no_privacy_mean", "observer_only_mse_mean",
                "max_rel_diff_privacy", "fused_mse_mean", "centralized_mse_mean"):
        assert col in rows[0]
    assert max(float(r["max_rel_diff_privacy"]) for r in rows) < 1e-9
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["seed"] == 4 and cfg["config"]["n_runs"] == 2 and "roadcollab_version" in cfg
    assert "![Fig. 4](fig4_mse.png)" in (out / "report.md").read_text()


def test_bad_profile_path_is_a_clear_error(tmp_path, capsys):
    # Refused while parsing (before --out is touched), as every file option is: argparse's exit status 2.
    with pytest.raises(SystemExit) as exc:
        main(["reproduce", "--runs", "1", "--out", str(tmp_path), "--road-profile", str(tmp_path / "nope.txt")])
    assert exc.value.code == 2
    assert "argument --road-profile: " in capsys.readouterr().err


def test_bad_run_count_is_refused_by_the_parser(tmp_path):
    with pytest.raises(SystemExit):
        main(["reproduce", "--runs", "0", "--out", str(tmp_path)])


@pytest.mark.parametrize("mechanism", ["none", "paper", "hardened", "fused", "secure_aggregation"])
def test_message_example_decodes(tmp_path, mechanism):
    path = tmp_path / f"{mechanism}.bin"
    assert main(["message", "example", "--mechanism", mechanism, "--out", str(path)]) == 0
    assert protocol.decode(path.read_bytes()).mechanism == mechanism


def test_message_example_secure_aggregation_is_a_masked_input(tmp_path, capsys):
    path = tmp_path / "secagg.bin"
    assert main(["message", "example", "--mechanism", "secure_aggregation", "--out", str(path), "--seed", "3"]) == 0
    data = path.read_bytes()
    msg = protocol.decode(data)
    assert type(msg).__name__ == "MaskedInput" and msg.vehicle == 1 and msg.y.shape == (600, 2)
    assert len(data) == 48 + 16 * 600 and protocol.encode(msg) == data
    assert "MaskedInput" in capsys.readouterr().out


def test_readme_api_example_runs():
    code = README.read_text().split("```python")[1].split("```")[0]
    exec(compile(code, "README.md", "exec"), {})


def test_estimate_bad_drive_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "drive1.csv"
    bad.write_text("time_s,accel_left\n0,1\n")
    assert main(["estimate", "--drive", str(bad), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "drive1.csv" in err and "roadcollab estimate: error:" in err


@pytest.mark.slow     # end-to-end: a whole study or a worker pool (make test-slow)
def test_anomalies_writes_detection_csv(tmp_path):
    out = tmp_path / "an"
    assert main(["anomalies", "--runs", "1", "--vehicles", "3", "--no-sweeps", "--out", str(out)]) == 0
    rows = _read_csv(out / "detection.csv")
    assert [r["estimator"] for r in rows] == ["observer_only", "collaborative", "fused"]
    for col in ("precision", "recall", "f1", "median_position_error_m"):
        assert 0.0 <= float(rows[1][col]) <= 1.0 or col == "median_position_error_m"
    assert (out / "fig_anomaly_map.png").stat().st_size > 0
