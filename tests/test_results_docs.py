"""tools/make_results_docs.py: docs/results.md is the CSVs' content, not typed-in numbers."""

import csv
import importlib.util
from pathlib import Path

TOOL = Path(__file__).resolve().parents[1] / "tools" / "make_results_docs.py"


def _tool():
    spec = importlib.util.spec_from_file_location("make_results_docs", TOOL)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_tables_come_from_the_csv_and_missing_studies_say_which_command(tmp_path):
    demo = tmp_path / "results" / "demo"
    demo.mkdir(parents=True)
    with open(demo / "bound_check.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["estimator", "vehicle", "mean_excess", "stderr", "z"])
        w.writerow(["fused", 1, 1.23456789e-4, 2e-6, 61.7283945])
        w.writerow(["oracle_per_bin_windowed", 1, -3e-7, 1e-7, -3.0])
    out = tmp_path / "results.md"
    assert _tool().main(["x", str(tmp_path / "results"), str(out)]) == 0
    text = out.read_text()
    assert "| estimator | vehicle | mean_excess | stderr | z |" in text
    assert "| fused | 1 | 0.0001235 | 2e-06 | 61.73 |" in text
    assert "| oracle_per_bin_windowed | 1 | -3e-07 | 1e-07 | -3 |" in text
    assert "Not generated in this build: run `roadcollab sweep --out results/sweep --workers 2`" in text
