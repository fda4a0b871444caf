"""Figures of ``roadcollab attack``: Fig. 11 (attack success per mechanism) and the privacy/accuracy frontier.

With the other ``plotting*`` modules, one of the modules that import matplotlib.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Sequence

import numpy as np

from .plotting_base import legend_outside, plt, save_figure

__all__ = ["plot_attack_success", "plot_privacy_frontier"]

_NUMBER = re.compile(r"(\d+(?:\.\d+)?)")


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


def _grouped(rows: Sequence) -> tuple[list, np.ndarray, list]:
    """Rows sorted by mechanism (natural order; attacks in their given order), their x positions with a gap
    between mechanisms, and the groups ``(mechanism, first x, last x)``."""
    rows = sorted(rows, key=lambda r: _natural_key(str(_field(r, "mechanism"))))   # stable: attack order kept
    x, groups, pos = [], [], 0.0
    for i, r in enumerate(rows):
        mech = str(_field(r, "mechanism"))
        if i and mech != groups[-1][0]:
            pos += 0.8
        if not groups or mech != groups[-1][0]:
            groups.append([mech, pos, pos])
        groups[-1][2] = pos
        x.append(pos)
        pos += 1.0
    return rows, np.array(x), [tuple(g) for g in groups]


def _error_panel(ax, y: np.ndarray, err: np.ndarray) -> None:
    """Median relative pole error on a log axis: finite errors as bars, zero and infinite ones written out."""
    finite = err[np.isfinite(err) & (err > 0)]
    lo = float(finite.min()) / 4 if finite.size else 1e-3
    hi = float(finite.max()) * 4 if finite.size else 10.0
    lo, hi = min(lo, 0.02), max(hi, 0.5)  # keep the 0.1 line in view
    ax.set_xscale("log")
    ax.set_xlim(lo, hi)
    ok = np.isfinite(err) & (err > 0)
    ax.barh(y[ok], err[ok], color="tab:blue", label="median relative pole error")
    inf = np.isposinf(err)
    if inf.any():
        ax.barh(y[inf], np.full(inf.sum(), hi), color="none", edgecolor="tab:red", hatch="//",
                label="infinite: the attack found no pole")
    for yi, e in zip(y, err):
        if e == 0:
            ax.text(lo * 1.15, yi, "0\n(exact)", ha="left", va="center", fontsize=8, color="tab:green")
        elif np.isposinf(e):
            ax.text(np.sqrt(lo * hi), yi, "inf (nothing found)", ha="center", va="center", fontsize=8,
                    color="tab:red", bbox={"fc": "white", "ec": "none", "alpha": 0.8, "pad": 1})
        elif not np.isfinite(e):
            ax.text(lo * 1.15, yi, "n/a", ha="left", va="center", fontsize=8, color="grey")
    ax.axvline(0.1, color="k", ls="--", lw=1, label="relative error 0.1")


def plot_attack_success(rows: Sequence, path) -> Path:
    """Fig. 11: success rate and median relative pole error per attack, grouped by mechanism.

    One row per attack, top to bottom (horizontal bars, so the figure grows in height with the
    number of attacks and its labels stay legible at any count): the success rate on the left, the
    pole error on the right. Mechanisms are sorted by name, separated by horizontal lines and named
    in the right margin. Success rates are written beside their bars (so a zero is visible). Pole
    errors are bars on a log axis; an error of exactly zero is written as "0", an infinite one (the
    attack returned no pole) as a hatched bar to the edge marked "inf (nothing found)", and nothing
    is clipped.

    Parameters
    ----------
    rows : sequence of dict or of objects
        ``attack.csv`` rows with ``mechanism`` (str), ``attack`` (str), ``success_rate`` (in
        [0, 1]) and ``median_rel_pole_error`` (>= 0, may be infinite or NaN), as keys or attributes.
    path : str or Path
        Output image (format from the suffix, 120 dpi).

    Returns
    -------
    Path
        ``path``.
    """
    rows, y, groups = _grouped(rows)
    height = max(4.0, 0.3 * (y[-1] + 1.0) + 2.0)     # 0.3 in per row: 9-point labels do not touch
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11.0, height), sharey=True,
                                 gridspec_kw={"width_ratios": [1.0, 1.3]})
    rate = np.array([float(_field(r, "success_rate")) for r in rows])
    err = np.array([float(_field(r, "median_rel_pole_error")) for r in rows])
    a1.barh(y, rate, color="tab:red")
    for yi, v in zip(y, rate):
        a1.text(v + 0.02, yi, "0" if v == 0 else f"{v:.2f}", ha="left", va="center", fontsize=8)
    a1.set_xlabel("success rate (all poles within 1 %)", fontsize=9)
    a1.set_xlim(0, 1.2)
    _error_panel(a2, y, err)
    a2.set_xlabel("median relative pole error", fontsize=9)
    a1.set_yticks(y)
    a1.set_yticklabels([_attack_label(r) for r in rows], fontsize=9)
    a1.set_ylim(y[-1] + 0.7, y[0] - 0.7)               # first row at the top
    for ax in (a1, a2):
        ax.grid(True, axis="x", alpha=0.3)
        ax.tick_params(axis="x", labelsize=8)
        for (_, _, last), (_, first, _) in zip(groups[:-1], groups[1:]):
            ax.axhline(0.5 * (last + first), color="k", lw=0.8)
    for mech, first, last in groups:   # names in the right margin, beside their group: no overflow
        a2.text(1.02, 0.5 * (first + last), mech, transform=a2.get_yaxis_transform(), ha="left", va="center",
                fontsize=9, fontweight="bold")
    a2.legend(loc="lower left", bbox_to_anchor=(0.0, 1.01), ncol=2, fontsize=8, borderaxespad=0.0)
    fig.suptitle("Fig. 11: how often the attacks recover the poles of $S_j$, per mechanism", fontsize=11)
    return save_figure(fig, path)


def plot_privacy_frontier(points: Sequence, path) -> Path:
    """For each mechanism, its strongest attack's success and pole error against the MSE it costs.

    Parameters
    ----------
    points : sequence
        Objects with ``mechanism`` (str), ``mse`` ((m/s)^2, the receivers' estimation error),
        ``success_rate`` (in [0, 1]) and ``median_rel_pole_error`` (>= 0, may be infinite)
        attributes: one per mechanism, for its strongest attack.
    path : str or Path
        Output image (format from the suffix, 120 dpi).

    Returns
    -------
    Path
        ``path``.
    """
    points = list(points)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(14, 5))
    cmap = plt.get_cmap("tab10")
    markers = "osD^vP*Xhp<>"
    # Several mechanisms sit at one point (success 0 or 1 at similar MSE): hollow markers of decreasing
    # size, each a distinct colour-and-shape pair, stay visible as concentric outlines.
    sizes = np.linspace(480.0, 40.0, max(len(points), 2))
    handles = []
    for i, p in enumerate(points):
        c, m = cmap(i % 10), markers[i % len(markers)]
        err = float(p.median_rel_pole_error)
        # Log axis: exact recovery (error 0) is drawn at 1e-16, nothing found (inf) and >= 10 at 10.
        shown = 10.0 if not np.isfinite(err) else min(max(err, 1e-16), 10.0)
        style = {"facecolors": "none", "edgecolors": [c], "marker": m, "s": sizes[i], "linewidths": 1.6,
                 "zorder": 3 + i}
        handles.append(a1.scatter(p.mse, p.success_rate, label=f"{p.mechanism} ({p.attack})", **style))
        a2.scatter(p.mse, shown, **style)
    a1.set_xscale("log")
    a1.set_ylim(-0.03, 1.03)
    a1.set_xlabel("receivers' road-velocity MSE ((m/s)$^2$)")
    a1.set_ylabel("strongest attack: success rate\n(all poles within 1 %)")
    a1.set_title("Attack success vs accuracy")
    a1.grid(True, which="both", alpha=0.3)
    a2.set_xscale("log")
    a2.set_yscale("log")
    a2.axhline(0.1, color="k", ls="--", lw=1)
    a2.set_xlabel("receivers' road-velocity MSE ((m/s)$^2$)")
    a2.set_ylabel("strongest attack: median relative pole error\n(0 drawn at 1e-16, >= 10 or none found at 10)")
    a2.set_title("Attacker's error vs accuracy")
    a2.grid(True, which="both", alpha=0.3)
    legend = legend_outside(a2, handles=handles, title="mechanism (strongest attack)")
    for h in legend.legend_handles:   # one size in the legend, whatever the size on the axes
        h.set_sizes([70.0])
    return save_figure(fig, path)
