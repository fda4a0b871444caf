"""Figure of ``roadcollab iri``: IRI per road segment (Agg backend, files only)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .plotting_base import legend_outside, plt, save_figure

__all__ = ["plot_iri"]


def plot_iri(start, end, series: dict, path, *, title: str) -> Path:
    """IRI per segment as steps over road position, one line per labelled series.

    Parameters
    ----------
    start : (s,) array_like
        Segment starts, m.
    end : (s,) array_like
        Segment ends, m.
    series : dict
        ``{label: (s,) array_like}``, IRI in m/km, drawn in insertion order.
    path : str or Path
        Output image (format from the suffix, 120 dpi).
    title : str
        Figure title.

    Returns
    -------
    Path
        ``path``.
    """
    start, end = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    edges = np.r_[start, end[-1]]
    fig, ax = plt.subplots(figsize=(9, 3.8))
    styles = (("tab:gray", 2.4, "-"), ("tab:blue", 1.2, "--"), ("tab:orange", 1.2, ":"))
    for i, (label, values) in enumerate(series.items()):
        color, lw, ls = styles[i % len(styles)]
        values = np.asarray(values, dtype=float)
        ax.stairs(values, edges, color=color, lw=lw, ls=ls, label=label, baseline=None)
    ax.set_ylim(bottom=0)
    ax.set_xlabel("road position (m)")
    ax.set_ylabel("IRI (m/km)")
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    legend_outside(ax)
    return save_figure(fig, path)
