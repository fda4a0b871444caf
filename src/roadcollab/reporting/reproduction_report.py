"""Outputs of ``roadcollab reproduce``: the MSE tables, Figs. 4-7, the fleet, ``config.json`` and ``report.md``.

Every sentence of the report's summary is worded from the numbers (:func:`reproduction_summary`).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from . import plotting
from ..experiments.reproduction.study import ESTIMATORS
from ..experiments.reproduction.iri import iri_ratios
from ..experiments.reproduction.rows import (WINDOWED_CONTROL, BoundRow, FleetRow, FusionRow, IriRow, MseRow, RunTraces,
                                             TraceRow)
from .figure_queue import FigureQueue
from .records import markdown_table, output_dir, write_config, write_rows
from .wording import plural

__all__ = ["headline_table", "reproduction_summary", "write_reproduction"]

#: The headline table of the report and the CLI: (:class:`MseRow` field, header).
_HEADLINE = (("vehicle", "vehicle"), ("observer_only_mse_mean", "observer only"),
             ("own_inversion_mse_mean", "own inversion"),
             ("own_posterior_inversion_mse_mean", "own posterior inv."), ("mse_mean", "Alg. 1+2"),
             ("mse_no_privacy_mean", "Alg. 1"), ("fused_mse_mean", "fused"),
             ("fused_posterior_mse_mean", "fused (posterior)"), ("centralized_mse_mean", "centralized"),
             ("oracle_per_bin_mse_mean", "per-bin oracle"), ("max_rel_diff_privacy", "max rel diff privacy"))
#: Fleet columns shown in the report (``fleet.csv`` holds every parameter).
_FLEET_REPORT_COLUMNS = ["vehicle", "true_sprung_mass", "estimated_sprung_mass", "true_stiffness",
                         "estimated_stiffness", "true_damping", "estimated_damping"]
#: Vehicles whose estimates are plotted against the truth (Figs. 5-7).
_N_TRACE_FIGURES = 3


def _mean_over(key: str, rows: list[MseRow]) -> float:
    """Mean of the field ``key`` over ``rows`` (NaN without rows)."""
    return float(np.mean([getattr(r, key) for r in rows])) if rows else float("nan")


def headline_table(rows: list[MseRow]) -> tuple[list[str], list[tuple]]:
    """The headline columns of ``mse.csv`` rows, for the report and the command line.

    Parameters
    ----------
    rows : list of MseRow
        :meth:`~roadcollab.experiments.reproduction.study.ReproductionResult.table` rows.

    Returns
    -------
    headers : list of str
        Column headers.
    values : list of tuple
        Per row, the vehicle number then the MSEs ((m/s)^2) and the privacy figure.
    """
    return [h for _, h in _HEADLINE], [tuple(getattr(r, name) for name, _ in _HEADLINE) for r in rows]


def reproduction_summary(rows: list[MseRow], bound_rows: list[BoundRow] | None = None) -> dict:
    """Headline numbers of a reproduction (used by the report and the CLI).

    Parameters
    ----------
    rows : list of MseRow
        :meth:`~roadcollab.experiments.reproduction.study.ReproductionResult.table` rows.
    bound_rows : list of BoundRow, optional
        :meth:`~roadcollab.experiments.reproduction.study.ReproductionResult.bound_check` rows.

    Returns
    -------
    dict
        Ratios of MSEs (dimensionless) and exactness figures.
    """
    V = len(rows)
    v1 = rows[0]
    later = rows[1:]
    k5 = min(5, V) - 1
    out: dict[str, float | int | str | bool | None] = {
        "vehicle1_observer_mse": v1.observer_only_mse_mean,
        "vehicle1_observer_over_own_inversion": v1.observer_only_mse_mean / v1.own_inversion_mse_mean,
        "algorithm1_mean_mse": _mean_over("mse_mean", later),
        "vehicle1_observer_over_algorithm1": v1.observer_only_mse_mean / _mean_over("mse_mean", later),
        "observer_over_algorithm1_same_vehicles":
            _mean_over("observer_only_mse_mean", later) / _mean_over("mse_mean", later),
        "own_inversion_over_algorithm1_same_vehicles":
            _mean_over("own_inversion_mse_mean", later) / _mean_over("mse_mean", later),
        "own_posterior_inversion_over_algorithm1_same_vehicles":
            _mean_over("own_posterior_inversion_mse_mean", later) / _mean_over("mse_mean", later),
        "max_rel_diff_privacy": max(r.max_rel_diff_privacy for r in rows),
        "theorem1_e_max": max(r.theorem1_e_max for r in rows),
        "theorem1_wf_max": max(r.theorem1_wf_max for r in rows),
        "theorem1_e_band_max": max(r.theorem1_e_band_max for r in rows),
        "theorem1_wf_band_max": max(r.theorem1_wf_band_max for r in rows),
        "fused_over_centralized_last": rows[-1].fused_mse_mean / rows[-1].centralized_mse_mean,
        "algorithm1_over_fused_last": rows[-1].mse_mean / rows[-1].fused_mse_mean,
        "fused_posterior_over_centralized_last": rows[-1].fused_posterior_mse_mean / rows[-1].centralized_mse_mean,
        "algorithm1_over_fused_posterior_last": rows[-1].mse_mean / rows[-1].fused_posterior_mse_mean,
        "vehicle1_observer_over_fused5": v1.observer_only_mse_mean / rows[k5].fused_mse_mean,
        "vehicle1_observer_over_fused_posterior5": v1.observer_only_mse_mean / rows[k5].fused_posterior_mse_mean,
        "fused5_vehicles": k5 + 1,
        "oracle_over_fused_last": rows[-1].oracle_per_bin_mse_mean / rows[-1].fused_mse_mean,
    }
    if not later:  # one vehicle: Algorithm 1 has no predecessor, so there is nothing to compare (None, not NaN)
        out.update({k: None for k in _ALGORITHM1_KEYS})
    estimators = [r for r in bound_rows or () if r.estimator != WINDOWED_CONTROL]
    if estimators:
        worst = min(estimators, key=lambda r: r.z)
        out.update(bound_min_z=worst.z, bound_min_z_estimator=worst.estimator,
                   bound_min_z_vehicle=worst.vehicle, bound_beaten=bool(worst.z < -3))
    control = [r for r in bound_rows or () if r.estimator == WINDOWED_CONTROL]
    if control:
        out.update(control_max_z=max(r.z for r in control), control_min_z=min(r.z for r in control))
    return out


_ALGORITHM1_KEYS = ("algorithm1_mean_mse", "vehicle1_observer_over_algorithm1",
                    "observer_over_algorithm1_same_vehicles", "own_inversion_over_algorithm1_same_vehicles",
                    "own_posterior_inversion_over_algorithm1_same_vehicles")


def _ratio_words(ratio: float) -> str:
    """``other / this`` as "2.1x better" or "2.1x worse"."""
    return f"{ratio:.2f}x better" if ratio >= 1 else f"{1 / ratio:.2f}x worse"


def _summary_lines(summary: dict, n_vehicles: int) -> list[str]:
    """The report's summary bullets, worded from the numbers."""
    s = summary
    alg1 = ("- Algorithm 1 needs a predecessor: with one vehicle there is no Algorithm 1 estimate to compare."
            if s["algorithm1_mean_mse"] is None else None)
    return [
        f"- Vehicle 1's lag-free online estimate (observer only) has MSE {s['vehicle1_observer_mse']:.4g}, "
        f"{s['vehicle1_observer_over_own_inversion']:.2f}x its own offline inversion.",
        alg1 or f"- Algorithm 1 (vehicles 2..{n_vehicles}, mean MSE {s['algorithm1_mean_mse']:.4g}) is "
        f"{_ratio_words(s['vehicle1_observer_over_algorithm1'])} than vehicle 1's online estimate. On the same "
        f"vehicles it is {_ratio_words(s['observer_over_algorithm1_same_vehicles'])} than their own online "
        f"estimates, {_ratio_words(s['own_inversion_over_algorithm1_same_vehicles'])} than their own offline "
        f"inversions and {_ratio_words(s['own_posterior_inversion_over_algorithm1_same_vehicles'])} than their own "
        "posterior inversions.",
        f"- Privacy (Algorithm 2) changes no estimate by more than {s['max_rel_diff_privacy']:.2g} relative (the "
        "receiver's estimate from the obfuscated message vs. from the clear one). Measured on the message itself, "
        f"in band: the sent e~ matches Psi1 e within {s['theorem1_e_band_max']:.2g} over the band "
        f"({s['theorem1_e_max']:.2g} in the worst bin, where e is a small residual of two large terms) and the sent "
        f"w~f matches Psi2^-1 w^f within {s['theorem1_wf_band_max']:.2g} ({s['theorem1_wf_max']:.2g} worst bin).",
        f"- Fused estimate at vehicle {n_vehicles} (average of nominal inversions): "
        f"{s['fused_over_centralized_last']:.2f}x the centralized linear MMSE and "
        f"{s['algorithm1_over_fused_last']:.1f}x better than Algorithm 1; the per-bin oracle is "
        f"{1 / s['oracle_over_fused_last']:.0f}x below it. Fused from posterior inversions: "
        f"{s['fused_posterior_over_centralized_last']:.2f}x the centralized MMSE and "
        f"{s['algorithm1_over_fused_posterior_last']:.1f}x better than Algorithm 1.",
        f"- The fused estimate of {s['fused5_vehicles']} vehicles is "
        f"{_ratio_words(s['vehicle1_observer_over_fused5'])} (posterior: "
        f"{_ratio_words(s['vehicle1_observer_over_fused_posterior5'])}) than vehicle 1's online estimate.",
    ] + ([
        "- Per-bin oracle: " + ("**beaten** " if s["bound_beaten"] else "not beaten ")
        + f"(smallest paired z-score of any estimator's excess MSE over it: {s['bound_min_z']:.1f}, "
        f"{s['bound_min_z_estimator']} at vehicle {s['bound_min_z_vehicle']}; beaten means z < -3). It is the best "
        "estimator per bin of the padded grid, not a bound on the window's error: its own estimate zeroed outside the "
        f"window (`{WINDOWED_CONTROL}`, a control) has z from {s.get('control_min_z', float('nan')):.1f} to "
        f"{s.get('control_max_z', float('nan')):.1f}."]
        if "bound_min_z" in s else [])


def _headline_table(rows: list[MseRow]) -> str:
    """The report's MSE table: the :func:`headline_table` of ``mse.csv`` rows."""
    headers, values = headline_table(rows)
    return markdown_table([dict(zip(headers, v)) for v in values], headers)


def _write_trace_figures(traces: RunTraces, out: Path, clock: FigureQueue) -> list[str]:
    """Figs. 5-7 (a 3 s window of run 1) with their CSVs; returns the file stems written."""
    names = []
    for j in range(min(_N_TRACE_FIGURES, len(traces.plain))):
        name = f"fig{5 + j}_vehicle{j + 1}"
        write_rows(out / f"{name}.csv", traces.to_rows(j), TraceRow)
        t0 = float(traces.time[0])
        clock(plotting.plot_estimates, traces.time, traces.truth, traces.plain[j], traces.private[j], j + 1,
                                out / f"{name}.png", window=(t0 + 5.0, t0 + 8.0))
        names.append(name)
    return names


def _intro_lines(result, command: str, elapsed: float) -> list[str]:
    """Title, run description and the definitions of the estimators."""
    cfg = result.config
    road = cfg.road_profile or f"synthetic ISO 8608 class {cfg.iso_class}"
    return [
        "# roadcollab reproduction: collaborative estimation with privacy (Figs. 4-7)",
        "",
        f"Command: `{command}`  ",
        f"Seed {result.seed}; {plural(cfg.n_runs, 'run')} x {plural(cfg.n_vehicles, 'vehicle')}; {elapsed:.1f} s.  ",
        f"Road: {road}; speed {cfg.speed:g} m/s; {cfg.sample_rate:g} Hz; scored segment "
        f"{cfg.segment_length:g} m (+{cfg.margin:g} m lead-in/out); sensor noise {cfg.sensor_noise_std:g} m/s^2; "
        f"parameter uncertainty {100 * cfg.fleet.estimate_uncertainty:g} % (1 sigma); fleet spread "
        f"+-{100 * cfg.fleet.spread:g} %; observer gamma {cfg.gamma:g}; band from {cfg.band_low_hz:g} Hz.",
        "",
        "MSE is the mean square of the band-limited road-velocity error over the scored segment, both tracks, "
        "(m/s)^2, averaged over runs; NMSE divides by the band-limited truth's mean square. DC and the lowest "
        "frequencies are invisible to accelerometers and are excluded identically for every estimator.",
        "",
        "Estimators, all scored the same way: *observer only* = the vehicle's own lag-free online estimator "
        "(Lemma 1 + eq. 4); *own inversion* = its own offline inversion W_reg P_hat^-1 y of its own record; *own posterior inv.* = "
        "the same with the posterior-mean plant E[P | estimated parameters] under the public fleet distribution; "
        "*Alg. 1+2* = Algorithm 1 with Algorithm 2 (the paper's estimate), *Alg. 1* without privacy; *fused* = the "
        "running average of the inversions z of vehicles 1..j; *fused (posterior)* = the same with each vehicle "
        "inverting its posterior-mean plant; *centralized* = the linear MMSE from the raw records "
        "of vehicles 1..j with their nominal models and the known statistics (parameter uncertainty, road spectrum, "
        "sensor noise); *per-bin oracle* = the linear MMSE with the true models per bin of the padded grid (no "
        "per-bin estimator should beat it on average; `bound_check.csv` tests that, and its control "
        "`oracle_per_bin_windowed`, the same estimate zeroed outside the window, shows that it is not a bound on the "
        "window's error).",
        "",
    ]


def _results_lines(summary: dict, rows: list[MseRow], n_vehicles: int, trace_figures: list[str]) -> list[str]:
    """Summary bullets, the MSE table and Figs. 4-7."""
    lines = [
        "## Summary",
        "",
        *_summary_lines(summary, n_vehicles),
        "",
        "## MSE per vehicle (`mse.csv`, (m/s)^2)",
        "",
        _headline_table(rows),
        "",
        "## Fig. 4: MSE per vehicle",
        "",
        "![Fig. 4](fig4_mse.png)",
        "",
        "## Fused, centralized and oracle estimates",
        "",
        "Bars: 95 % confidence interval of the mean over runs (`fig_fusion.csv` holds means, standard deviations "
        "and intervals).",
        "",
        "![fusion](fig_fusion.png)",
        "",
        "## Figs. 5-7: actual road input vs estimates with and without privacy (run 1, a 3 s window)",
        "",
        "Below each track's signals, the error of each estimate (estimate - actual, RMS over the window in the "
        "legend).",
        "",
    ]
    for j, name in enumerate(trace_figures):
        lines += [f"![Vehicle {j + 1}]({name}.png)", ""]
    return lines


def _ratio_cell(mean: float, std: float) -> str:
    """``mean +- std`` of a ratio for the IRI table."""
    return f"{mean:.3f} +- {std:.3f}"


def _iri_lines(rows: list[IriRow], estimators, config) -> list[str]:
    """The IRI comparison of the measured runs: mean true IRI and the table of estimated / true ratios."""
    if not rows:
        return []
    ratios = {(r.estimator, r.track): r for r in iri_ratios(rows, estimators)}
    table = [{"estimator": name,
              **{f"{t} {ref}": _ratio_cell(getattr(ratios[name, t], f"ratio_{ref}"),
                                           getattr(ratios[name, t], f"ratio_{ref}_std"))
                 for t in ("left", "both") for ref in ("raw", "band")}} for name in estimators]
    left = [r for r in rows if r.track == "left"]
    seg = rows[0].end_m - rows[0].start_m
    band_m = config.speed / config.band_low_hz
    return [
        "### Road roughness: estimated against true IRI (`iri_measured.csv`)",
        "",
        f"Golden Car IRI (ASTM E1926, 80 km/h) per {seg:g} m segment of the scored {config.segment_length:g} m "
        f"({plural(len({r.start_m for r in rows}), 'segment')} per run and track, "
        f"{plural(len({r.run for r in rows}), 'run')}), of "
        f"vehicle {rows[0].vehicle}'s estimates (the fleet estimates use vehicles 1..{rows[0].vehicle}). Each "
        "estimate's elevation is its band-limited road-velocity estimate integrated over distance (increment "
        "w / fs per sample). It lacks wavelengths above "
        f"{band_m:g} m (speed / band edge) while the IRI responds to about 1.2-30 m, so the truth is given twice: "
        "*raw* = the profile the vehicles drove over, *band* = that profile band-limited like the estimates. "
        f"Mean true IRI of the measured (left) track: raw {np.mean([r.true_iri_raw for r in left]):.3f} m/km, "
        f"band-limited {np.mean([r.true_iri_band_limited for r in left]):.3f} m/km.",
        "",
        "Mean of estimated / true IRI per segment (+- std over runs and segments); *left* is the measured track, "
        "*both* adds the right track (measured plus a synthetic residual):",
        "",
        markdown_table(table, list(table[0].keys())),
        "",
    ]


def _measured_section(measured, out: Path, clock: FigureQueue) -> list[str]:
    """The run on the shipped measured profile: writes ``mse_measured.csv`` and its figure, returns report lines."""
    mres, mel = measured
    mrows = mres.table()
    write_rows(out / "mse_measured.csv", mrows, MseRow)
    frows = mres.fusion_rows()
    write_rows(out / "fig_measured_mse.csv", frows, FusionRow)
    irows = mres.iri_rows()
    if irows:
        write_rows(out / "iri_measured.csv", irows, IriRow)
    clock(plotting.plot_fusion, frows, out / "fig_measured_mse.png", title=(
        f"Measured profile: MSE per vehicle of the fleet estimates (mean over {plural(mres.config.n_runs, 'run')}; "
        "bars: 95 % CI)"))
    ms = reproduction_summary(mrows, mres.bound_check())
    mc = mres.config
    return [
        "## Measured road profile (shipped with the package)",
        "",
        f"`profile_1.txt` (MIT licence beside it): one measured track; the second track is the measured one plus "
        f"an independent ISO class A residual high-passed at 20 m. {plural(mc.n_runs, 'run')}, same fleet and seed, "
        f"speed {mc.speed:g} m/s, scored {mc.segment_length:g} m; {mel:.1f} s. The online estimators are still "
        f"designed for an ISO class {mc.iso_class} road; the linear MMSE estimates use the measured road's own "
        "spectrum.",
        "",
        *_summary_lines(ms, mc.n_vehicles),
        "",
        _headline_table(mrows),
        "",
        "![measured](fig_measured_mse.png)",
        "",
        *_iri_lines(irows, ESTIMATORS, mc),
    ]


def _fleet_lines(fleet_rows: list[FleetRow]) -> list[str]:
    """The fleet table of the report."""
    return ["## Fleet (`fleet.csv`)", "", markdown_table(fleet_rows, _FLEET_REPORT_COLUMNS), ""]


def write_reproduction(result, out, *, command: str, elapsed: float, measured=None, timings: dict | None = None,
                       workers: int | None = None) -> dict:
    """Write every output of ``roadcollab reproduce`` to the folder ``out``.

    Files: ``mse.csv``, ``bound_check.csv``, ``fig4_mse.png``, ``fig_fusion.png`` with ``fig_fusion.csv``,
    ``fig5..7_vehicle{1..3}.png`` with their CSVs, ``fleet.csv``, ``config.json`` and ``report.md``;
    with ``measured`` also ``mse_measured.csv``, ``fig_measured_mse.png`` with its CSV and, when the measured run
    compared IRIs, ``iri_measured.csv``.

    Parameters
    ----------
    result : roadcollab.experiments.reproduction.study.ReproductionResult
        The reproduction to report.
    out : str or Path
        Output folder (created if missing; files overwritten).
    command : str
        The command line, recorded in ``config.json`` and the report.
    elapsed : float
        Wall-clock time of the reproduction, s.
    measured : (ReproductionResult, float), optional
        The run on the measured road profile and its wall-clock time, s.
    timings : dict of str to float, optional
        Wall time of the command's phases, s; recorded in ``config.json`` (``timings_s``) and the report
        with the time spent here writing the outputs (``report_s``) and the figures in it (``figures_s``).
    workers : int, optional
        With 2 or more, the figures are drawn at the end on up to that many processes
        (:class:`~roadcollab.reporting.figure_queue.FigureQueue`); the same files.

    Returns
    -------
    dict
        :func:`reproduction_summary` of ``result``.
    """
    t0, clock = time.perf_counter(), FigureQueue(workers)
    out = output_dir(out)
    rows = result.table()
    bound = result.bound_check()
    write_rows(out / "mse.csv", rows, MseRow)
    write_rows(out / "bound_check.csv", bound, BoundRow)
    clock(plotting.plot_mse, rows, out / "fig4_mse.png")
    fusion_rows = result.fusion_rows()
    write_rows(out / "fig_fusion.csv", fusion_rows, FusionRow)
    clock(plotting.plot_fusion, fusion_rows, out / "fig_fusion.png")
    trace_figures = _write_trace_figures(result.runs[0].traces, out, clock)
    fleet_rows = result.fleet_rows()
    write_rows(out / "fleet.csv", fleet_rows, FleetRow)
    summary = reproduction_summary(rows, bound)
    lines = _intro_lines(result, command, elapsed)
    lines += _results_lines(summary, rows, result.config.n_vehicles, trace_figures)
    if measured is not None:
        lines += _measured_section(measured, out, clock)
    lines += _fleet_lines(fleet_rows)
    clock.finish()
    timings = {**(timings or {}), "figures_s": clock.seconds,
               "report_s": time.perf_counter() - t0}
    lines += _timing_lines(timings)
    (out / "report.md").write_text("\n".join(lines))
    write_config(out / "config.json", command=command, seed=result.seed, config=result.config.to_dict(),
                 extra={"elapsed_s": elapsed, "timings_s": timings, "summary": summary})
    return summary


def _timing_lines(timings: dict) -> list[str]:
    """The report's timing section (wall time per phase, s)."""
    return ["## Timings (wall clock, s)", "",
            "; ".join(f"{k.removesuffix('_s').replace('_', ' ')} {v:.2f}" if isinstance(v, float) else f"{k} {v}"
                      for k, v in timings.items()) + ".", ""]
