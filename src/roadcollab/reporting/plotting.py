"""Figures of ``roadcollab reproduce``, ``attack`` and ``anomalies`` (Agg backend, files only).

With the other ``plotting_*`` modules (:mod:`~roadcollab.reporting.plotting_base` holds the backend and
:func:`save_figure`), the only modules that import matplotlib. Fig. 11 (:func:`plot_attack_success`) lives
in :mod:`~roadcollab.reporting.plotting_security` and is re-exported here.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .plotting_base import legend_outside, plt, save_figure
from .plotting_security import plot_attack_success
from .wording import plural

__all__ = ["save_figure", "plot_mse", "plot_fusion", "plot_estimates", "plot_poles", "plot_attack_success",
           "plot_anomaly_map", "plot_f1_vs_depth", "plot_f1_vs_noise"]

_TRACKS = ("left track", "right track")


def _mse_axes(ax, vehicles) -> None:
    """Log MSE axis over vehicle numbers, shared by the MSE figures."""
    ax.set_yscale("log")
    ax.set_xlabel("vehicle")
    ax.set_ylabel("road-velocity MSE ((m/s)$^2$)")
    ax.set_xticks(vehicles)
    ax.grid(True, which="both", alpha=0.3)


def plot_mse(rows: list, path) -> Path:
    """Fig. 4: MSE per vehicle of every estimator (mean over runs; std bars for Algorithm 1 + 2
    and the online observer).

    Parameters
    ----------
    rows : list of MseRow
        ``mse.csv`` rows.
    path : str or Path
        Output image.

    Returns
    -------
    Path
    """
    v = np.array([r.vehicle for r in rows])
    fig, ax = plt.subplots(figsize=(10, 4.8))
    ax.errorbar(v, [r.mse_mean for r in rows], yerr=[r.mse_std for r in rows], fmt="o-", capsize=4,
                label="Algorithm 1 + 2 (collaborative, private)")
    ax.errorbar(v + 0.1, [r.observer_only_mse_mean for r in rows], yerr=[r.observer_only_mse_std for r in rows],
                fmt="s--", capsize=4, alpha=0.8, label="observer only (own, online)")
    for key, label, style in (("own_inversion_mse_mean", "own inversion (own, offline)", "d:"),
                              ("own_posterior_inversion_mse_mean", "own posterior inversion", "x:"),
                              ("fused_mse_mean", "fused (average of z, vehicles 1..j)", "^-"),
                              ("fused_posterior_mse_mean", "fused, posterior inversions (1..j)", "<-"),
                              ("centralized_mse_mean", "centralized linear MMSE (1..j)", "v-."),
                              ("oracle_per_bin_mse_mean", "per-bin oracle (true models, 1..j)", "k:")):
        ax.plot(v, [getattr(r, key) for r in rows], style, label=label)
    _mse_axes(ax, v)
    legend_outside(ax, fontsize=7)
    ax.set_title("Fig. 4: MSE per vehicle of every estimator (mean over runs; bars: std)")
    return save_figure(fig, path)


#: The fusion figure's estimators: (estimator of :class:`FusionRow`, label, format).
_FUSION_LINES = (("observer_only", "observer only (own, online)", "s--"),
                 ("algorithm1_private", "Algorithm 1 + 2", "o-"),
                 ("fused", "fused (average of z)", "^-"),
                 ("fused_posterior", "fused (posterior inversions)", "<-"),
                 ("centralized", "centralized linear MMSE", "v-."),
                 ("oracle_per_bin", "per-bin oracle", "k:"))


def plot_fusion(rows: list, path, *, title: str | None = None) -> Path:
    """MSE vs vehicle for the fleet estimates, with 95 % confidence intervals of the mean over runs.

    Lines: observer only, Algorithm 1 + 2, fused, fused posterior, centralized and the oracle
    bound; each offset slightly along the vehicle axis so the bars do not overlap. On the log axis
    a lower bar end at or below zero is drawn down to 1 % of the mean.

    Parameters
    ----------
    rows : list of FusionRow
        :meth:`~roadcollab.experiments.reproduction.study.ReproductionResult.fusion_rows` (MSE in (m/s)^2).
    path : str or Path
        Output image.
    title : str, optional
        Figure title (default: names the runs and the bars).

    Returns
    -------
    Path
    """
    fig, ax = plt.subplots(figsize=(9.5, 4.2))
    runs = max((r.runs for r in rows), default=0)
    for i, (name, label, style) in enumerate(_FUSION_LINES):
        sel = sorted((r for r in rows if r.estimator == name), key=lambda r: r.vehicle)
        if not sel:
            continue
        v = np.array([r.vehicle for r in sel], dtype=float) + 0.06 * (i - (len(_FUSION_LINES) - 1) / 2)
        mean = np.array([r.mse_mean for r in sel])
        ci = np.array([r.mse_ci95 for r in sel])
        ax.errorbar(v, mean, yerr=[np.minimum(ci, 0.99 * mean), ci], fmt=style, capsize=3, lw=1.2, ms=5,
                    label=label)
    _mse_axes(ax, sorted({r.vehicle for r in rows}))
    legend_outside(ax)
    ax.set_title(title or f"MSE per vehicle of the fleet estimates (mean over {plural(runs, 'run')}; bars: 95 % CI)",
                 fontsize=10)
    return save_figure(fig, path)


def _rms(x) -> float:
    """Root mean square, NaN for no samples."""
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x ** 2))) if x.size else float("nan")


def plot_estimates(time, truth, plain, private, vehicle: int, path, *, window: tuple[float, float] | None = None
                   ) -> Path:
    """Figs. 5-7: actual (band-limited) road input vs the estimates with and without privacy, and the error.

    Per track two panels on one time axis: the signals, then the residuals ``estimate - truth``
    of the estimate without and with privacy (RMS over the window in the legend; the two residuals
    differ by Algorithm 2's numerical error only, so the dashed one lies on the solid one).

    Parameters
    ----------
    time : (N,) array_like
        s.
    truth : (N, 2) ndarray
        Band-limited road velocity, m/s, columns ``[left, right]``.
    plain, private : (N, 2) ndarray
        The vehicle's estimates without and with privacy (Algorithm 2), m/s.
    vehicle : int
        Vehicle number (1-based), for the title.
    path : str or Path
        Output image (format from the suffix, 120 dpi).
    window : (float, float), optional
        Time span ``(start, end)`` to plot, s, both ends included (default: everything).

    Returns
    -------
    Path
        ``path``.
    """
    time = np.asarray(time)
    sel = slice(None) if window is None else (time >= window[0]) & (time <= window[1])
    t, truth, plain, private = time[sel], np.asarray(truth)[sel], np.asarray(plain)[sel], np.asarray(private)[sel]
    fig, axes = plt.subplots(4, 1, figsize=(10, 7.5), sharex=True, gridspec_kw={"height_ratios": [2, 1, 2, 1]})
    for c in range(2):
        ax, res = axes[2 * c], axes[2 * c + 1]
        ax.plot(t, truth[:, c], "k-", lw=1.2, label="actual (band-limited)")
        ax.plot(t, plain[:, c], "-", color="tab:blue", lw=1.0, label="estimate without privacy")
        ax.plot(t, private[:, c], "--", color="tab:orange", lw=1.0, label="estimate with privacy")
        ax.set_ylabel(f"{_TRACKS[c]}\nw (m/s)")
        res.axhline(0.0, color="k", lw=0.6)
        res.plot(t, plain[:, c] - truth[:, c], "-", color="tab:blue", lw=1.0,
                 label=f"without privacy (RMS {_rms(plain[:, c] - truth[:, c]):.3g} m/s)")
        res.plot(t, private[:, c] - truth[:, c], "--", color="tab:orange", lw=1.0,
                 label=f"with privacy (RMS {_rms(private[:, c] - truth[:, c]):.3g} m/s)")
        res.set_ylabel("error\n(m/s)")
        lim = 1.1 * float(np.max(np.abs(np.r_[plain[:, c], private[:, c]] - np.r_[truth[:, c], truth[:, c]]),
                                 initial=1e-12))
        res.set_ylim(-lim, lim)
        legend_outside(ax)
        legend_outside(res, title="estimate - actual")
        for a in (ax, res):
            a.grid(True, alpha=0.3)
    axes[0].set_title(f"Figs. 5-7, vehicle {vehicle}: road-velocity input, its estimates (Algorithm 1) and their "
                      "errors", fontsize=10)
    axes[-1].set_xlabel("time (s)")
    return save_figure(fig, path)


def plot_poles(example: dict, path) -> Path:
    """Figs. 8-10: actual vs estimated poles of S_j in the complex plane (rad/s).

    Parameters
    ----------
    example : dict
        ``"vehicle"`` (1-based), ``"true"`` poles and, when present, the poles estimated by the
        ``"model_reduction"``, ``"pole_intersection"`` and ``"multiplicity"`` attacks (complex, rad/s).
    path : str or Path
        Output image (format from the suffix, 120 dpi).

    Returns
    -------
    Path
        ``path``.
    """
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
    ax.legend(fontsize=8, loc="best", framealpha=0.85)
    ax.set_title(f"Vehicle {example['vehicle']}: poles of $S_j$ and the attackers' estimates")
    lim = 2.5 * float(np.max(np.abs(t)))
    ax.set_xlim(-lim, 0.2 * lim)
    ax.set_ylim(-lim, lim)
    return save_figure(fig, path)


# --- road anomaly detection (roadcollab.experiments.anomalies.study) ----------------------------------------

_ESTIMATOR_STYLE = {"observer_only": ("tab:gray", "s", "observer only"),
                    "collaborative": ("tab:blue", "o", "collaborative (Algorithm 1)"),
                    "fused": ("tab:green", "D", "fused (average of z)")}
_KIND_COLOR = {"pothole": "tab:red", "bump": "tab:orange"}


#: Rows of the road map per side (left track at 1, right at 0; "both" spans the two).
_MAP_ROWS = {"left": (1.0,), "right": (0.0,), "both": (1.0, 0.0)}


def _signed_depth_cm(anomaly) -> float:
    """Depth in cm, negative for potholes and positive for bumps."""
    sign = -1.0 if anomaly.kind == "pothole" else 1.0
    return sign * 100 * anomaly.depth


def _draw_true_anomalies(ax, ax2, truth) -> None:
    """True anomalies: shaded spans on their tracks (``ax``) and signed-depth bars (``ax2``)."""
    for a in truth:
        for y in _MAP_ROWS[a.side]:
            ax.add_patch(plt.Rectangle((a.position, y - 0.42), max(a.end - a.position, 0.3), 0.84,
                                       color=_KIND_COLOR[a.kind], alpha=0.35, lw=0))
        ax.annotate(f"{100 * a.depth:.1f}", (a.center, 1.5), ha="center", fontsize=7,
                    color=_KIND_COLOR[a.kind])
        ax2.bar(a.center, _signed_depth_cm(a), width=max(a.end - a.position, 0.6),
                color=_KIND_COLOR[a.kind], alpha=0.35)


def _draw_detections(ax, ax2, dets: dict) -> None:
    """Each estimator's detections: markers sized by depth on their tracks (offset per estimator, ``ax``) and
    signed depths (``ax2``)."""
    names = [n for n in _ESTIMATOR_STYLE if n in dets] + [n for n in dets if n not in _ESTIMATOR_STYLE]
    for i, name in enumerate(names):
        color, _, label = _ESTIMATOR_STYLE.get(name, ("k", "x", name))
        off = 0.25 * (i - (len(names) - 1) / 2)
        for d in dets[name]:
            marker = "v" if d.kind == "pothole" else "^"
            size = 20 + 1500 * d.depth
            for y in _MAP_ROWS[d.side]:
                ax.scatter(d.position, y + off, s=size, marker=marker, color=color, edgecolor="k", lw=0.4,
                           zorder=3)
            ax2.plot(d.position, _signed_depth_cm(d), marker, color=color, mec="k", mew=0.4, ms=6)
        ax.scatter([], [], marker="o", color=color, label=label)


def _label_map(ax, ax2, map_example) -> None:
    """Legend, limits, ticks and titles of the road map."""
    for kind, color in _KIND_COLOR.items():
        ax.add_patch(plt.Rectangle((0, 0), 0, 0, color=color, alpha=0.35, label=f"true {kind} (depth in cm)"))
    ax.set_xlim(*map_example.region)
    ax.set_ylim(-0.6, 1.8)
    ax.set_yticks([0.0, 1.0])
    ax.set_yticklabels(["right track", "left track"])
    ax.legend(fontsize=7, ncol=3, loc="lower center", bbox_to_anchor=(0.5, 1.0))
    ax.set_title(f"Run {map_example.run}, vehicle {map_example.vehicle}: "
                 "true anomalies (spans) and detections (v pothole, ^ bump; size ~ depth)", fontsize=9, pad=36)
    ax2.axhline(0, color="k", lw=0.5)
    ax2.set_ylabel("depth (cm)\npothole < 0 < bump")
    ax2.set_xlabel("position along the road (m)")
    ax2.grid(True, alpha=0.3)


def plot_anomaly_map(map_example, path) -> Path:
    """Road map of true vs detected anomalies for one run and vehicle.

    Top: position along the road (x) against the two wheel tracks (rows); true anomalies are
    shaded spans coloured by kind (a ``"both"`` anomaly spans both rows), detections of each
    estimator are markers (triangle down = pothole, up = bump) whose size grows with the
    estimated depth. Bottom: signed depth in cm (potholes negative, bumps positive), true vs
    estimated, so depth errors can be read off.

    Parameters
    ----------
    map_example : AnomalyMap
        True anomalies, every estimator's detections, the region shown (m), run and vehicle.
    path : str or Path
        Output image (format from the suffix, 120 dpi).

    Returns
    -------
    Path
        ``path``.
    """
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(11, 5.5), sharex=True, gridspec_kw={"height_ratios": [1.2, 1]})
    _draw_true_anomalies(ax, ax2, map_example.truth)
    _draw_detections(ax, ax2, map_example.detections)
    _label_map(ax, ax2, map_example)
    return save_figure(fig, path)


def _plot_f1_vs(rows: list, key: str, path, xlabel: str, *, scale: float = 1.0, logx: bool = False,
                title: str = "") -> Path:
    fig, ax = plt.subplots(figsize=(9.5, 4))
    names = list(dict.fromkeys(r.estimator for r in rows))
    for name in names:
        sel = sorted((r for r in rows if r.estimator == name), key=lambda r: getattr(r, key))
        x = np.array([getattr(r, key) for r in sel]) * scale
        color, marker, label = _ESTIMATOR_STYLE.get(name, (None, "x", name))
        ax.plot(x, [r.f1 for r in sel], "-", marker=marker, color=color, label=f"{label}: F1")
        ax.plot(x, [r.recall for r in sel], ":", marker=marker, color=color, alpha=0.6, mfc="none",
                label=f"{label}: recall")
    ax.axhline(0.9, color="k", ls="--", lw=0.8)
    if logx:
        ax.set_xscale("log")
    ax.set_ylim(0, 1.02)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("F1 / recall")
    ax.grid(True, which="both", alpha=0.3)
    legend_outside(ax, fontsize=7)
    ax.set_title(title, fontsize=9)
    return save_figure(fig, path)


def plot_f1_vs_depth(rows: list, path) -> Path:
    """F1 (solid) and recall (dotted) of anomaly detection per estimator vs anomaly depth.

    Parameters
    ----------
    rows : list of DepthDetectionRow
        ``AnomalyStudyResult.depth_rows``.
    path : str or Path
        Output image.

    Returns
    -------
    Path
    """
    return _plot_f1_vs(rows, "depth_m", path, "anomaly depth / height (cm)", scale=100.0,
                       title="Anomaly detection vs depth (dashed: F1 = 0.9)")


def plot_f1_vs_noise(rows: list, path) -> Path:
    """F1 (solid) and recall (dotted) per estimator vs accelerometer noise std.

    Parameters
    ----------
    rows : list of NoiseDetectionRow
        ``AnomalyStudyResult.noise_rows``.
    path : str or Path
        Output image.

    Returns
    -------
    Path
    """
    return _plot_f1_vs(rows, "sensor_noise_std", path, "accelerometer noise std (m/s$^2$)", logx=True,
                       title="Anomaly detection vs sensor noise (estimators designed for the default)")
