"""Figs. 11 and 12 stay legible (issue 23, section 5b): sizes, fonts and legends that cover nothing."""

from types import SimpleNamespace

import matplotlib.image
import numpy as np
import pytest

from roadcollab.reporting import plotting_security as ps


def _rows(n):
    mechs = ["none", "paper", "paper_vehicle", "hardened", "dp(eps=0.5)", "dp(eps=2)", "secure_aggregation"]
    return [{"mechanism": mechs[i % len(mechs)], "attack": f"attack_{i}", "road": "fused", "segments": 3,
             "success_rate": (i % 5) / 4, "median_rel_pole_error": [0.0, np.inf, 1e-3, 0.5][i % 4]} for i in range(n)]


@pytest.mark.parametrize("n", [5, 35])
def test_fig11_width_is_bounded_and_height_grows_with_the_rows(tmp_path, n):
    shape = matplotlib.image.imread(ps.plot_attack_success(_rows(n), tmp_path / "f.png")).shape
    assert shape[1] == 1320                        # 11 in at 120 dpi, whatever the number of attacks
    assert shape[0] >= 0.3 * 120 * n               # at least 0.3 in per attack row


def test_fig11_labels_are_at_least_8_points(tmp_path, monkeypatch):
    sizes = []
    real = ps.plt.Axes.text
    monkeypatch.setattr(ps.plt.Axes, "text", lambda self, *a, **k: sizes.append(k.get("fontsize")) or real(self, *a, **k))
    ps.plot_attack_success(_rows(35), tmp_path / "f.png")
    assert sizes and min(sizes) >= 8


def test_fig12_legend_lists_every_mechanism_outside_both_axes(tmp_path, monkeypatch):
    pts = [SimpleNamespace(mechanism=m, attack="replica", mse=1e-4, success_rate=float(i % 2),
                           median_rel_pole_error=0.0 if i % 2 else np.inf)
           for i, m in enumerate(["none", "paper", "paper_vehicle", "hardened", "dp(eps=2)", "secure_aggregation"])]
    captured = {}
    real = ps.save_figure

    def spy(fig, path):
        fig.canvas.draw()
        captured["fig"] = fig
        captured["extents"] = [ax.get_window_extent() for ax in fig.axes]
        captured["legend"] = fig.axes[1].get_legend().get_window_extent()
        captured["labels"] = [t.get_text() for t in fig.axes[1].get_legend().get_texts()]
        captured["sizes"] = [h.get_sizes()[0] for h in fig.axes[1].get_legend().legend_handles]
        return real(fig, path)

    monkeypatch.setattr(ps, "save_figure", spy)
    ps.plot_privacy_frontier(pts, tmp_path / "f.png")
    assert captured["labels"] == [f"{p.mechanism} ({p.attack})" for p in pts]
    assert all(not captured["legend"].overlaps(e) for e in captured["extents"])
    assert len(set(captured["sizes"])) == 1
