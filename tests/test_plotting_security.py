"""Figs. 11 and 12 stay legible at print size (issue 23, section 5b): 12 in at 150 dpi, texts of at least 9 pt
that overlap no other text, legend entries inside the figure, no marker covering another."""

import itertools
import math
from types import SimpleNamespace

import matplotlib.image
import matplotlib.text
import numpy as np
import pytest

from roadcollab.reporting import plotting_security as ps


def attack_rows(extra_attacks=0):
    """``attack.csv`` rows shaped like a small ``roadcollab attack`` run (every kind of cell)."""
    rows = []

    def add(m, a, s, e, road="-", seg=1):
        rows.append({"mechanism": m, "attack": a, "road": road, "segments": seg, "success_rate": s,
                     "median_rel_pole_error": e})
    for m in ("none", "paper"):
        add(m, "model_reduction", 0.0 if m == "paper" else 1.0, math.inf if m == "paper" else 0.0)
        add(m, "pole_intersection", 1.0, 2e-12)
        add(m, "multiplicity", 0.85, 3e-3)
    add("paper", "physical_fit", 0.65, 8e-3, "true")
    for a, e in (("model_reduction", 0.62), ("pole_intersection", math.inf), ("physical_fit", 0.041)):
        add("hardened", a, 0.0, e, "true" if a == "physical_fit" else "-")
    add("hardened", "physical_fit_own_road", 0.0, 0.12, "own")
    for road in ("true", "fused", "own"):
        for seg in (1, 3):
            add("hardened", "replica", 0.05 * seg, 0.02 / seg, road, seg)
    for eps, e in ((0.5, 0.9), (2, 0.31), (10, 0.07)):
        add(f"dp(eps={eps:g})", "physical_fit", 0.0 if eps < 10 else 0.1, e, "true")
    add("no_message", "prior_guess", 0.0, float("nan"))
    for i in range(extra_attacks):
        add("secure_aggregation", f"attack_{i}", (i % 5) / 4, [0.0, math.inf, 1e-3, 0.5][i % 4])
    return rows


def frontier(n=9):
    pts = [("none", "pole_intersection", 1.0, 2e-12, 1.05e-4), ("paper", "pole_intersection", 1.0, 2e-12, 1.05e-4),
           ("paper_vehicle", "physical_fit", 0.65, 8e-3, 1.05e-4), ("hardened", "replica", 0.15, 6.7e-3, 1.05e-4),
           ("dp(eps=0.5)", "physical_fit", 0.0, 0.9, 3.2e-2), ("dp(eps=2)", "physical_fit", 0.0, 0.31, 2.1e-3),
           ("dp(eps=10)", "physical_fit", 0.1, 0.07, 1.9e-4), ("secure_aggregation", "none", 0.0, math.inf, 1.05e-4),
           ("no_message", "prior_guess", 0.0, 0.0, 4.0e-4)]
    return [SimpleNamespace(mechanism=m, attack=a, road="-", segments=1, success_rate=s, median_rel_pole_error=e,
                            mse=x) for m, a, s, e, x in pts[:n]]


def _drawn(monkeypatch, plot, data, tmp_path):
    """Draw a figure, keep what its renderer laid out, and the PNG's pixel shape."""
    out = {}
    real = ps.save_figure

    def spy(fig, path, **kw):
        fig.canvas.draw()
        r = fig.canvas.get_renderer()
        hidden = {id(label) for ax in fig.axes for axis in (ax.xaxis, ax.yaxis)   # ticks outside the view: not drawn
                  for tick in axis.get_major_ticks() + axis.get_minor_ticks()
                  if not _inside(axis.get_view_interval(), tick.get_loc())
                  for label in (tick.label1, tick.label2)}
        out["texts"] = [(t.get_text(), t.get_window_extent(r), t.get_fontsize())
                        for t in fig.findobj(matplotlib.text.Text)
                        if t.get_visible() and t.get_text().strip() and id(t) not in hidden]
        out["figure"] = fig.bbox.frozen()
        out["legends"] = [[(t.get_window_extent(r), h) for t, h in zip(leg.get_texts(), leg.legend_handles)]
                          for leg in fig.legends + [a.get_legend() for a in fig.axes if a.get_legend()]]
        out["points"] = [(ax, c.get_offsets(), c.get_sizes(), c.get_offset_transform())
                         for ax in fig.axes for c in ax.collections if hasattr(c, "get_sizes") and len(c.get_offsets())]
        out["dpi"] = fig.dpi
        return real(fig, path, **kw)

    monkeypatch.setattr(ps, "save_figure", spy)
    out["shape"] = matplotlib.image.imread(plot(data, tmp_path / "f.png")).shape
    return out


def _inside(interval, x):
    lo, hi = sorted(interval)
    return lo - 1e-9 * abs(lo) <= x <= hi + 1e-9 * abs(hi)     # relative to each end: log axes too


def _overlapping(texts):
    return [(a[0], b[0]) for a, b in itertools.combinations(texts, 2) if a[1].shrunk(0.98, 0.9).overlaps(b[1])]


CASES = [(ps.plot_attack_success, attack_rows()), (ps.plot_privacy_frontier, frontier())]


@pytest.mark.parametrize("plot,data", CASES, ids=["fig11", "fig12"])
def test_print_size_fonts_and_no_overlapping_text(monkeypatch, tmp_path, plot, data):
    out = _drawn(monkeypatch, plot, data, tmp_path)
    h, w = out["shape"][:2]
    assert w == 1800 and 700 <= h <= 1300, (w, h)              # about 1800 x 1000 px at 150 dpi
    assert min(size for _, _, size in out["texts"]) >= 9
    assert _overlapping(out["texts"]) == []
    box = out["figure"]
    for text, ext, _ in out["texts"]:                          # nothing leaves the figure
        assert box.x0 - 1 <= ext.x0 and ext.x1 <= box.x1 + 1 and box.y0 - 1 <= ext.y0 and ext.y1 <= box.y1 + 1, text


@pytest.mark.slow  # 14 s: draws Fig. 11 at several sizes
def test_fig11_writes_every_cell_and_grows_in_height_only(monkeypatch, tmp_path):
    out = _drawn(monkeypatch, ps.plot_attack_success, attack_rows(), tmp_path)
    texts = [t for t, _, _ in out["texts"]]
    for must in ("0", "inf", "2e-12", "0.65", "n/a", "dp(eps=0.5)", "dp(eps=10)", "replica (road fused, 3 seg)"):
        assert must in texts, must
    assert texts.index("dp(eps=2)") < texts.index("dp(eps=10)")   # natural order of the columns
    big = _drawn(monkeypatch, ps.plot_attack_success, attack_rows(extra_attacks=30), tmp_path)
    assert big["shape"][1] == 1800 and big["shape"][0] >= 150 * 0.3 * 42   # 0.3 in per attack row
    assert _overlapping(big["texts"]) == []


def test_fig12_gives_every_mechanism_a_row_and_its_legend_lies_in_the_figure(monkeypatch, tmp_path):
    out = _drawn(monkeypatch, ps.plot_privacy_frontier, frontier(), tmp_path)
    texts = [t for t, _, _ in out["texts"]]
    rows = sorted((t for t in out["texts"] if "\n(" in t[0] and "strongest" not in t[0]), key=lambda t: -t[1].y0)   # top to bottom
    assert [t for t, _, _ in rows] == [f"{p.mechanism}\n({p.attack})" for p in
                                             sorted(frontier(), key=lambda p: (p.mse, p.mechanism))]
    assert "none found" in texts and "0 (exact)" in texts
    box = out["figure"]
    entries = [e for leg in out["legends"] for e in leg]
    assert len(entries) == 4
    for ext, _ in entries:
        assert box.x0 <= ext.x0 and ext.x1 <= box.x1 and box.y0 <= ext.y0 and ext.y1 <= box.y1
    # No marker covers another: centres at least one marker diameter apart within each panel.
    by_axes = {}
    for ax, offsets, sizes, transform in out["points"]:
        px = transform.transform(offsets)
        d = np.sqrt(np.broadcast_to(sizes, len(px))) * out["dpi"] / 72
        by_axes.setdefault(id(ax), []).extend(zip(px, d))
    for pts in by_axes.values():
        for (p, dp), (q, dq) in itertools.combinations(pts, 2):
            assert np.hypot(*(p - q)) >= 0.5 * (dp + dq)
