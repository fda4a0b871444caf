"""All figures. The only module that imports matplotlib (Agg backend, files only)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["plot_mse", "plot_fusion", "plot_estimates", "plot_poles", "plot_attack_success"]

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


def plot_poles(example: dict, path) -> Path:
    """Figs. 8-10: actual vs estimated poles of S_j in the complex plane (rad/s)."""
    fig, ax = plt.subplots(figsize=(6, 5))
    t = np.asarray(example["true"])
    ax.plot(t.real, t.imag, "ko", ms=10, mfc="none", mew=2, label="actual poles of $S_j$")
    for key, marker in (("model_reduction", "x"), ("pole_intersection", "+"), ("multiplicity", "1")):
        p = np.asarray(example.get(key, []))
        if p.size:
            ax.plot(p.real, p.imag, marker, ms=10, mew=2, label=f"{key.replace('_', ' ')} attack")
    ax.axvline(0, color="grey", lw=0.5)
    ax.set_xlabel("Re s (rad/s)")
    ax.set_ylabel("Im s (rad/s)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"Vehicle {example['vehicle']}: poles of $S_j$ and the attackers' estimates")
    lim = 2.5 * float(np.max(np.abs(t)))
    ax.set_xlim(-lim, 0.2 * lim)
    ax.set_ylim(-lim, lim)
    return _save(fig, path)


def plot_attack_success(rows: list[dict], path) -> Path:
    """Success rate and median relative pole error per mechanism and attack."""
    labels = [f"{r['mechanism']}\n{r['attack']}" for r in rows]
    x = np.arange(len(rows))
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(max(7, 0.8 * len(rows)), 6), sharex=True)
    a1.bar(x, [r["success_rate"] for r in rows], color="tab:red")
    a1.set_ylabel("success rate\n(all poles within 1 %)")
    a1.set_ylim(0, 1.05)
    a1.grid(True, axis="y", alpha=0.3)
    err = [min(r["median_rel_pole_error"], 1e3) for r in rows]
    a2.bar(x, err, color="tab:blue")
    a2.set_yscale("log")
    a2.axhline(0.1, color="k", ls="--", lw=1, label="0.1")
    a2.set_ylabel("median relative\npole error")
    a2.set_xticks(x)
    a2.set_xticklabels(labels, rotation=60, ha="right", fontsize=8)
    a2.legend()
    a2.grid(True, axis="y", alpha=0.3)
    return _save(fig, path)
