"""Figures of ``roadcollab attack``: Fig. 11 (attack success per mechanism) and the privacy/accuracy frontier.

With the other ``plotting*`` modules, one of the modules that import matplotlib.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from .plotting_base import plt, save_figure

if TYPE_CHECKING:                 # matplotlib is imported with pyplot, by plotting_base
    from matplotlib.image import AxesImage

__all__ = ["plot_attack_success", "plot_privacy_frontier"]

_NUMBER = re.compile(r"(\d+(?:\.\d+)?)")

#: Print size of Figs. 11 and 12: 12 in wide at 150 dpi (1800 px); every text is at least ``FONT_PT``.
WIDTH_IN, DPI, FONT_PT = 12.0, 150, 9.0


def _attack_label(row) -> str:
    """``attack`` plus, where the row says so, the road given and the segments combined."""
    label = str(_field(row, "attack"))
    try:
        road, segments = _field(row, "road"), int(_field(row, "segments"))
    except (KeyError, AttributeError, TypeError, ValueError):
        return label
    extra = [f"road {road}"] if road not in ("-", "") else []
    extra += [f"{segments} seg"] if segments > 1 else []
    return f"{label} ({', '.join(extra)})" if extra else label


def _field(row, name: str):
    """``row[name]`` of a dict row or ``row.name`` of a row object."""
    return row[name] if isinstance(row, dict) else getattr(row, name)


def _natural_key(text: str) -> tuple:
    """Sort key that orders numbers inside names by value (``dp(eps=2)`` before ``dp(eps=10)``)."""
    return tuple((0, float(p), "") if i % 2 else (1, 0.0, p) for i, p in enumerate(_NUMBER.split(text)))


def _table(rows: Sequence) -> tuple[list[str], list[str], np.ndarray, np.ndarray]:
    """Mechanisms (natural order), attack labels (order of first appearance) and the success rate and pole
    error per (attack, mechanism) cell, NaN where the attack was not run on the mechanism."""
    rows = sorted(rows, key=lambda r: _natural_key(str(_field(r, "mechanism"))))   # stable: attack order kept
    mechs = list(dict.fromkeys(str(_field(r, "mechanism")) for r in rows))
    labels = list(dict.fromkeys(_attack_label(r) for r in rows))
    rate = np.full((len(labels), len(mechs)), np.nan)
    err = np.full_like(rate, np.nan)
    for r in rows:
        i, k = labels.index(_attack_label(r)), mechs.index(str(_field(r, "mechanism")))
        rate[i, k], err[i, k] = float(_field(r, "success_rate")), float(_field(r, "median_rel_pole_error"))
    return mechs, labels, rate, err


def _short(e: float) -> str:
    """A pole error in at most five characters: ``0``, ``inf``, ``0.12``, ``3e-4``."""
    if e == 0:
        return "0"
    if np.isposinf(e):
        return "inf"
    if 0.01 <= e < 10:
        return f"{e:.2g}"
    mant, exp = f"{e:.0e}".split("e")
    return f"{mant}e{int(exp)}"


def _heat(ax, values: np.ndarray, shown: np.ndarray, text: list[list[str]], cmap: str, norm, ran: np.ndarray
          ) -> AxesImage:
    """Cells coloured by ``shown`` (NaN: no colour), annotated with ``text``; cells not run are grey."""
    cm = plt.get_cmap(cmap).with_extremes(bad="white")
    im = ax.imshow(np.ma.masked_invalid(shown), cmap=cm, norm=norm, aspect="auto", interpolation="nearest")
    from matplotlib.patches import Rectangle
    for (i, k), v in np.ndenumerate(values):
        if not ran[i, k]:
            ax.add_patch(Rectangle((k - 0.5, i - 0.5), 1, 1, fc="0.88", ec="none"))
            continue
        if np.isposinf(v):
            ax.add_patch(Rectangle((k - 0.5, i - 0.5), 1, 1, fc="white", ec="0.5", hatch="//", lw=0))
        r, g, b, _ = cm(norm(shown[i, k])) if np.isfinite(shown[i, k]) else (1.0, 1.0, 1.0, 1.0)
        dark = 0.299 * r + 0.587 * g + 0.114 * b < 0.5      # white text on dark cells
        ax.text(k, i, text[i][k], ha="center", va="center", fontsize=FONT_PT, color="white" if dark else "black",
                bbox=None if np.isfinite(shown[i, k]) else {"fc": "white", "ec": "none", "pad": 0.5})
    ax.set_xticks(np.arange(values.shape[1]) + 0.5, minor=True)
    ax.set_yticks(np.arange(values.shape[0]) + 0.5, minor=True)
    ax.grid(which="minor", color="white", lw=1.5)
    ax.tick_params(which="minor", length=0)
    return im


def plot_attack_success(rows: Sequence, path) -> Path:
    """Fig. 11: success rate and median relative pole error of every attack on every mechanism.

    Two heat maps side by side, one row per attack (with the road it is given and the segments it
    combines) and one column per mechanism (sorted by name, named at the top, written upright so that no
    header overflows its column): the success rate (0-1, red) on the left, the median relative pole
    error (log colour scale) on the right. Every cell carries its value as text; an error of exactly
    zero is written ``0`` (the attack recovers the poles exactly), an infinite one ``inf`` on a
    hatched cell (the attack found no pole), and cells of attacks not run on a mechanism are grey.
    12 in wide at 150 dpi (1800 px), every text at least 9 pt; the height grows with the attacks.

    Parameters
    ----------
    rows : sequence of dict or of objects
        ``attack.csv`` rows with ``mechanism`` (str), ``attack`` (str), ``success_rate`` (in
        [0, 1]) and ``median_rel_pole_error`` (>= 0, may be infinite or NaN), as keys or attributes;
        ``road`` and ``segments`` where present.
    path : str or Path
        Output image (format from the suffix, 150 dpi).

    Returns
    -------
    Path
        ``path``.
    """
    from matplotlib.colors import LogNorm, Normalize

    mechs, labels, rate, err = _table(rows)
    ran = ~np.isnan(rate)
    height = max(5.5, 0.3 * len(labels) + 3.6)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(WIDTH_IN, height), sharey=True, layout="constrained")
    rate_text = [["" if np.isnan(v) else "0" if v == 0 else f"{v:.2f}" for v in row] for row in rate]
    im1 = _heat(a1, rate, rate, rate_text, "Reds", Normalize(0.0, 1.0), ran)
    finite = err[np.isfinite(err) & (err > 0)]
    lo = min(float(finite.min()) if finite.size else 1e-3, 1e-2)
    hi = max(float(finite.max()) if finite.size else 1.0, 1.0)
    shown = np.where(np.isfinite(err) & (err > 0), err, np.nan)
    err_text = [["" if not ran[i, k] else "n/a" if np.isnan(v) else _short(v) for k, v in enumerate(row)]
                for i, row in enumerate(err)]
    im2 = _heat(a2, err, shown, err_text, "viridis", LogNorm(lo, hi), ran)
    a1.set_yticks(np.arange(len(labels)), labels, fontsize=FONT_PT)
    for ax, title in ((a1, "success rate (every pole within 1 %)"), (a2, "median relative pole error")):
        ax.set_xticks(np.arange(len(mechs)), mechs, fontsize=FONT_PT, rotation=90, ha="center", va="bottom")
        ax.xaxis.tick_top()
        ax.tick_params(axis="both", which="major", labelsize=FONT_PT, length=0)
        ax.set_title(title, fontsize=FONT_PT + 1, pad=8)
    c1 = fig.colorbar(im1, ax=a1, location="bottom", shrink=0.8, aspect=40)
    c1.set_label("success rate", fontsize=FONT_PT)
    c2 = fig.colorbar(im2, ax=a2, location="bottom", shrink=0.8, aspect=40)
    c2.set_label("pole error; 0: exact, inf (hatched): nothing found, grey: not run", fontsize=FONT_PT)
    for c in (c1, c2):
        c.ax.tick_params(labelsize=FONT_PT)
    fig.suptitle("Fig. 11: how well the attacks recover the poles of $S_j$, per mechanism", fontsize=FONT_PT + 2)
    return save_figure(fig, path, dpi=DPI, tight=False)


def plot_privacy_frontier(points: Sequence, path) -> Path:
    """Fig. 12: for each mechanism, what it costs (MSE) against what its strongest attack achieves.

    Small multiples that share one row per mechanism, sorted by MSE (cheapest at the top): the receivers'
    MSE, the strongest attack's success rate and its median relative pole error, so no two mechanisms
    share a point. Exact recovery (error 0) is drawn at the left edge of the error panel with a left
    triangle, "nothing found" (infinite error) at the right edge with a right triangle, and both are
    written out; the legend of these marks sits below the panels, inside the figure. 12 in wide at 150
    dpi, every text at least 9 pt.

    Parameters
    ----------
    points : sequence
        Objects with ``mechanism`` (str), ``attack`` (str), ``mse`` ((m/s)^2, the receivers' estimation
        error), ``success_rate`` (in [0, 1]) and ``median_rel_pole_error`` (>= 0, may be infinite)
        attributes: one per mechanism, for its strongest attack.
    path : str or Path
        Output image (format from the suffix, 150 dpi).

    Returns
    -------
    Path
        ``path``.
    """
    from matplotlib.lines import Line2D

    points = sorted(points, key=lambda p: (float(p.mse), _natural_key(str(p.mechanism))))
    y = np.arange(len(points))
    height = max(5.0, 0.42 * len(points) + 3.0)
    fig, (a0, a1, a2) = plt.subplots(1, 3, figsize=(WIDTH_IN, height), sharey=True, layout="constrained")
    mse = np.array([float(p.mse) for p in points])
    rate = np.array([float(p.success_rate) for p in points])
    err = np.array([float(p.median_rel_pole_error) for p in points])
    dot = {"s": 60, "color": "tab:blue", "edgecolors": "k", "linewidths": 0.6, "zorder": 3}
    a0.scatter(mse, y, marker="o", **dot)
    a0.set_xscale("log")
    a0.set_xlabel("receivers' road-velocity MSE ((m/s)$^2$)", fontsize=FONT_PT)
    a1.scatter(rate, y, marker="o", **dot)
    a1.set_xlim(-0.05, 1.05)
    a1.set_xlabel("strongest attack: success rate\n(every pole within 1 %)", fontsize=FONT_PT)
    finite = err[np.isfinite(err) & (err > 0)]
    lo = min(float(finite.min()) / 3 if finite.size else 1e-3, 1e-2)
    hi = max(float(finite.max()) * 3 if finite.size else 1.0, 1.0)
    a2.set_xscale("log")
    a2.set_xlim(lo / 2, hi * 2)                      # the edge marks stay inside the panel
    ok, zero, inf = np.isfinite(err) & (err > 0), err == 0, np.isposinf(err)
    a2.scatter(err[ok], y[ok], marker="o", **dot)
    a2.scatter(np.full(zero.sum(), lo), y[zero], marker="<", clip_on=False, **{**dot, "color": "tab:green"})
    a2.scatter(np.full(inf.sum(), hi), y[inf], marker=">", clip_on=False, **{**dot, "color": "tab:red"})
    for yi, e in zip(y, err):
        if e == 0 or np.isposinf(e) or np.isnan(e):
            where, ha = (lo * 1.6, "left") if e == 0 else (hi / 3.0, "right") if np.isposinf(e) else (np.sqrt(lo * hi),
                                                                                                      "center")
            a2.text(where, yi, "0 (exact)" if e == 0 else "none found" if np.isposinf(e) else "n/a", ha=ha,
                    va="center", fontsize=FONT_PT, zorder=4, bbox={"fc": "white", "ec": "none", "pad": 1.0})
    a2.axvline(0.1, color="k", ls="--", lw=1)
    a2.set_xlabel("strongest attack: median relative pole error", fontsize=FONT_PT)
    a0.set_yticks(y, [f"{p.mechanism}\n({p.attack})" for p in points], fontsize=FONT_PT)
    a0.set_ylim(len(points) - 0.5, -0.5)
    for ax in (a0, a1, a2):
        ax.grid(True, which="major", alpha=0.3)
        ax.tick_params(labelsize=FONT_PT)
    marks = [Line2D([], [], ls="none", marker="o", mfc="tab:blue", mec="k", ms=7, label="the mechanism's value"),
             Line2D([], [], ls="none", marker="<", mfc="tab:green", mec="k", ms=7, label="pole error 0: poles recovered exactly"),
             Line2D([], [], ls="none", marker=">", mfc="tab:red", mec="k", ms=7, label="infinite pole error: no pole found"),
             Line2D([], [], color="k", ls="--", lw=1, label="pole error 0.1")]
    fig.legend(handles=marks, loc="outside lower center", ncol=4, fontsize=FONT_PT, frameon=False)
    fig.suptitle("Fig. 12: privacy against accuracy, each mechanism's strongest attack (rows sorted by MSE)",
                 fontsize=FONT_PT + 2)
    return save_figure(fig, path, dpi=DPI, tight=False)
