"""Figures of ``roadcollab attack`` beyond the paper's: the privacy/accuracy frontier.

With :mod:`~roadcollab.reporting.plotting`, one of the modules that import matplotlib.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from .plotting import plt, save_figure

__all__ = ["plot_privacy_frontier"]


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
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.5))
    cmap = plt.get_cmap("tab10")
    for i, p in enumerate(points):
        c = cmap(i % 10)
        err = float(p.median_rel_pole_error)
        shown = min(err, 10.0) if np.isfinite(err) else 10.0
        a1.scatter(p.mse, p.success_rate, color=c, s=40, label=p.mechanism)
        a2.scatter(p.mse, shown, color=c, s=40, marker="^" if shown != err else "o")
    a1.set_xscale("log")
    a1.set_ylim(-0.03, 1.03)
    a1.set_xlabel("receivers' road-velocity MSE ((m/s)$^2$)")
    a1.set_ylabel("strongest attack: success rate\n(all poles within 1 %)")
    a1.set_title("Attack success vs accuracy")
    a1.grid(True, which="both", alpha=0.3)
    a1.legend(fontsize=8, loc="best")
    a2.set_xscale("log")
    a2.set_yscale("log")
    a2.axhline(0.1, color="k", ls="--", lw=1)
    a2.set_xlabel("receivers' road-velocity MSE ((m/s)$^2$)")
    a2.set_ylabel("strongest attack: median relative pole error\n(triangles: >= 10, clipped)")
    a2.set_title("Attacker's error vs accuracy (up and left = better)")
    a2.grid(True, which="both", alpha=0.3)
    return save_figure(fig, path)
