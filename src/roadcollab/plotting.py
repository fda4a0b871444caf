"""All figures. The only module that imports matplotlib (Agg backend, files only)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["plot_mse", "plot_fusion", "plot_estimates"]

_TRACKS = ("left track", "right track")


def _save(fig, path) -> Path:
    path = Path(path)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_mse(rows: list[dict], path) -> Path:
    """Fig. 4: mean and standard deviation of the MSE per vehicle (with privacy), and the
    vehicles' own observers for reference."""
    v = np.array([r["vehicle"] for r in rows])
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.errorbar(v, [r["mse_mean"] for r in rows], yerr=[r["mse_std"] for r in rows], fmt="o-", capsize=4,
                label="Algorithm 1 + 2 (collaborative, private)")
    ax.errorbar(v + 0.1, [r["observer_only_mse_mean"] for r in rows], yerr=[r["observer_only_mse_std"] for r in rows],
                fmt="s--", capsize=4, alpha=0.8, label="observer only (no collaboration)")
    ax.set_yscale("log")
    ax.set_xlabel("vehicle")
    ax.set_ylabel("road-velocity MSE ((m/s)$^2$)")
    ax.set_xticks(v)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    ax.set_title("MSE per vehicle (mean $\\pm$ std over runs)")
    return _save(fig, path)


def plot_fusion(rows: list[dict], path) -> Path:
    """MSE vs vehicle for observer-only, Algorithm 1, fused and centralised estimates."""
    v = np.array([r["vehicle"] for r in rows])
    fig, ax = plt.subplots(figsize=(7, 4))
    for key, label, style in (("observer_only_mse_mean", "observer only", "s--"),
                              ("mse_mean", "Algorithm 1", "o-"),
                              ("fused_mse_mean", "fused (average of z)", "^-"),
                              ("centralized_mse_mean", "centralised (all raw data)", "k:")):
        ax.plot(v, [r[key] for r in rows], style, label=label)
    ax.set_yscale("log")
    ax.set_xlabel("vehicle")
    ax.set_ylabel("road-velocity MSE ((m/s)$^2$)")
    ax.set_xticks(v)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    return _save(fig, path)


def plot_estimates(time, truth, plain, private, vehicle: int, path, *, window: tuple[float, float] | None = None
                   ) -> Path:
    """Figs. 5-7: actual (band-limited) road input vs the estimates with and without privacy."""
    time = np.asarray(time)
    sel = slice(None) if window is None else (time >= window[0]) & (time <= window[1])
    fig, axes = plt.subplots(2, 1, figsize=(8, 5), sharex=True)
    for c, ax in enumerate(axes):
        ax.plot(time[sel], truth[sel, c], "k-", lw=1.2, label="actual (band-limited)")
        ax.plot(time[sel], plain[sel, c], "-", lw=1.0, label="estimate without privacy")
        ax.plot(time[sel], private[sel, c], "--", lw=1.0, label="estimate with privacy")
        ax.set_ylabel(f"{_TRACKS[c]}\nw (m/s)")
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title(f"Vehicle {vehicle}: road-velocity input and its estimates")
    axes[-1].set_xlabel("time (s)")
    return _save(fig, path)
