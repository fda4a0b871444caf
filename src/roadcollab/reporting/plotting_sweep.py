"""Figure of ``roadcollab sweep``: MSE against the observer parameter. Matplotlib, Agg backend, files only."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from .plotting_base import legend_outside, plt, save_figure

__all__ = ["plot_sweep"]


def _draw_panel(ax, panel: list, n_vehicles: int) -> list:
    """The lines of one (noise, uncertainty) panel, ``panel`` sorted by gamma; returns their legend handles."""
    V = n_vehicles
    g = np.array([r.gamma for r in panel])
    handles = [
        ax.errorbar(g, [r.vehicle1_observer_mse for r in panel],
                    yerr=np.nan_to_num([r.vehicle1_observer_mse_se for r in panel]), fmt="s--", capsize=3,
                    color="tab:gray", label="vehicle 1: own observer"),
        ax.errorbar(g, [r.algorithm1_mse for r in panel],
                    yerr=np.nan_to_num([r.algorithm1_mse_se for r in panel]), fmt="o-", capsize=3,
                    color="tab:blue", label=f"Algorithm 1 (vehicles 2..{V})"),
    ]
    handles += ax.plot(g, [r.own_inversion_mse for r in panel], "v:", color="tab:green",
                       label="own offline inversion")
    handles += ax.plot(g, [r.fused_mse for r in panel], "^-", color="tab:orange", label=f"fused, vehicle {V}")
    handles += ax.plot(g, [r.oracle_per_bin_mse for r in panel], "k-.", label=f"per-bin oracle, vehicle {V}")
    return handles


def _label_panel(ax, noise: float, uncertainty: float, *, bottom: bool, left: bool) -> None:
    """Log axes, grid and title of a panel; axis labels on the bottom row and left column only."""
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title(f"noise {noise:g} m/s$^2$, uncertainty {100 * uncertainty:g} %", fontsize=10)
    if bottom:
        ax.set_xlabel(r"observer parameter $\gamma$")
    if left:
        ax.set_ylabel("road-velocity MSE ((m/s)$^2$)")


def plot_sweep(rows: Sequence, path) -> Path:
    """MSE vs gamma (log-log), one panel per (sensor noise, parameter uncertainty) pair.

    Lines: vehicle 1's own observer and Algorithm 1 (vehicles 2..V; both with +-1 standard
    error bars over runs), each vehicle's own offline inversion, the fused estimate and the
    per-bin oracle at vehicle V.

    Parameters
    ----------
    rows : sequence of roadcollab.experiments.sweep.study.SweepRow
        The sweep's table (:meth:`roadcollab.experiments.sweep.study.SweepResult.table`); MSE in (m/s)^2.
    path : str or Path
        Output image (format from the suffix, 120 dpi).

    Returns
    -------
    Path
        ``path``.
    """
    rows = list(rows)
    noises = sorted({r.sensor_noise_std for r in rows})
    uncerts = sorted({r.parameter_uncertainty for r in rows})
    fig, axes = plt.subplots(len(noises), len(uncerts), figsize=(4.6 * len(uncerts) + 2.4, 3.6 * len(noises) + 0.4),
                             sharex=True, sharey=True, squeeze=False)
    for i, s in enumerate(noises):
        for k, u in enumerate(uncerts):
            ax = axes[i, k]
            panel = sorted((r for r in rows if r.sensor_noise_std == s and r.parameter_uncertainty == u),
                           key=lambda r: r.gamma)
            handles = _draw_panel(ax, panel, rows[0].n_vehicles)
            if i == 0 and k == len(uncerts) - 1:
                legend_outside(ax, handles=handles, fontsize=7)
            _label_panel(ax, s, u, bottom=i == len(noises) - 1, left=k == 0)
    fig.suptitle("Road-velocity MSE vs observer parameter $\\gamma$\n(mean over runs; bars: $\\pm$1 standard error)",
                 fontsize=10)
    return save_figure(fig, path)
