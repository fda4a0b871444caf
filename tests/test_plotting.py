"""Figures: Fig. 11 groups by mechanism and writes zero and infinite errors out; the other figures draw."""

import math
from types import SimpleNamespace

import matplotlib.image
import numpy as np
import pytest

from roadcollab.experiments.reproduction.rows import FusionRow
from roadcollab.reporting import plotting
from roadcollab.reporting.plotting_security import _table

_ATTACKS = [("paper", "model_reduction", 0.0, math.inf), ("none", "model_reduction", 1.0, 0.0),
            ("none", "pole_intersection", 0.5, 3e-3), ("hardened", "multiplicity", 0.0, 5e4),
            ("paper", "pole_intersection", 0.0, 0.8)]


def test_fig11_tabulates_attacks_by_sorted_mechanism_keeping_the_attack_order():
    mechs, labels, rate, err = _table([dict(zip(("mechanism", "attack", "success_rate", "median_rel_pole_error"), a))
                                       for a in _ATTACKS])
    assert mechs == ["hardened", "none", "paper"]
    assert labels == ["multiplicity", "model_reduction", "pole_intersection"]   # first appearance after sorting
    np.testing.assert_array_equal(rate, [[0.0, np.nan, np.nan], [np.nan, 1.0, 0.0], [np.nan, 0.5, 0.0]])
    np.testing.assert_array_equal(err, [[5e4, np.nan, np.nan], [np.nan, 0.0, math.inf], [np.nan, 3e-3, 0.8]])


@pytest.mark.parametrize("kind", ["dict", "object"])
def test_fig11_accepts_dicts_and_objects_and_writes_zero_and_inf(tmp_path, kind, monkeypatch):
    keys = ("mechanism", "attack", "success_rate", "median_rel_pole_error")
    rows = [dict(zip(keys, a)) if kind == "dict" else SimpleNamespace(**dict(zip(keys, a))) for a in _ATTACKS]
    texts = []
    real = plotting.plt.Axes.text
    monkeypatch.setattr(plotting.plt.Axes, "text", lambda self, *a, **k: texts.append(a[2]) or real(self, *a, **k))
    path = plotting.plot_attack_success(rows, tmp_path / "fig11.png")
    assert matplotlib.image.imread(path).shape[0] > 300
    assert {"inf", "0", "5e4", "3e-3", "0.8", "0.50", "1.00"} <= set(texts)


def test_fusion_figure_and_estimates_with_residuals_draw(tmp_path):
    rows = [FusionRow(name, v, 1e-3 / v, 5e-4 / v, 2e-3 / v, 4) for name in ("observer_only", "fused", "oracle_per_bin")
            for v in (1, 2, 3)]
    assert plotting.plot_fusion(rows, tmp_path / "fusion.png").stat().st_size > 0
    t = np.arange(600) / 200.0
    truth = np.column_stack([np.sin(t), np.cos(t)])
    path = plotting.plot_estimates(t, truth, truth + 0.01, truth + 0.01, 1, tmp_path / "fig5.png", window=(0.5, 2.5))
    assert matplotlib.image.imread(path).shape[0] > 700  # four panels: signals and errors per track
