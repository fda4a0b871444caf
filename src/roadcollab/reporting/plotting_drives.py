"""Figures of ``roadcollab estimate`` (recorded drives). Matplotlib, Agg backend, files only."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .plotting_base import legend_outside, plt, save_figure

__all__ = ["plot_tracks"]

_TRACKS = ("left track", "right track")
_STYLES = (("tab:gray", "-", 1.6, 0.7), ("tab:orange", "-", 1.0, 0.95), ("tab:green", "--", 1.0, 0.95),
           ("tab:blue", ":", 1.0, 0.95))


def plot_tracks(positions, series: dict, path, *, ylabel: str, title: str = "",
                zoom: tuple[float, float] | None = None) -> Path:
    """One row per track (left, right) with every labelled (N, 2) series against road position (m).

    With ``zoom = (start_m, end_m)`` a second column shows that stretch of road (shaded in the
    first column).

    Parameters
    ----------
    positions : (N,) array_like
        Road position of every sample, m.
    series : dict
        ``{label: (N, 2) array_like}``, columns ``[left, right]``, in the unit of ``ylabel``;
        drawn in insertion order.
    path : str or Path
        Output image (format from the suffix, 120 dpi).
    ylabel : str
        y-axis label with its unit, e.g. ``"road velocity (m/s)"``.
    title : str
        Title of the first column (default: from ``ylabel``).
    zoom : (float, float), optional
        ``(start_m, end_m)``, m, both ends included.

    Returns
    -------
    Path
        ``path``.
    """
    positions = np.asarray(positions, dtype=float)
    ncol = 1 if zoom is None else 2
    fig, axes = plt.subplots(2, ncol, figsize=(12 if zoom else 10, 5.5), sharex="col", squeeze=False,
                             gridspec_kw={"width_ratios": [3, 1]} if zoom else None)
    sel = slice(None) if zoom is None else (positions >= zoom[0]) & (positions <= zoom[1])
    for c in range(2):
        for col in range(ncol):
            ax = axes[c, col]
            s = slice(None) if col == 0 else sel
            for i, (label, data) in enumerate(series.items()):
                color, ls, lw, alpha = _STYLES[i % len(_STYLES)]
                data = np.asarray(data, dtype=float)
                ax.plot(positions[s], data[s, c], ls, color=color, lw=lw, alpha=alpha, label=label)
            ax.grid(True, alpha=0.3)
            if col == 0 and zoom is not None:
                ax.axvspan(zoom[0], zoom[1], color="k", alpha=0.08, lw=0)
        axes[c, 0].set_ylabel(f"{_TRACKS[c]}\n{ylabel}")
    legend_outside(axes[0, -1])
    axes[0, 0].set_title(title or f"{ylabel[:1].upper()}{ylabel[1:]} per track", fontsize=10)
    if zoom is not None:
        axes[0, 1].set_title(f"zoom {zoom[0]:.0f}-{zoom[1]:.0f} m", fontsize=10)
        axes[-1, 1].set_xlabel("position (m)")
    axes[-1, 0].set_xlabel("position along the road (m)")
    return save_figure(fig, path)
