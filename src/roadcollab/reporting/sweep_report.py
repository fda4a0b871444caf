"""Outputs of ``roadcollab sweep``: ``sweep.csv``, ``sweep.png``, ``config.json`` and ``report.md``.

Every statement of the report is generated from the sweep's numbers
(:meth:`roadcollab.experiments.sweep.study.SweepResult.findings`); nothing is hard-coded.
"""

from __future__ import annotations

import dataclasses

from ..experiments.sweep.findings import SweepFinding
from ..experiments.sweep.result import SweepResult, SweepRow
from .plotting_sweep import plot_sweep
from .records import markdown_table, output_dir, write_config, write_rows
from .wording import plural

__all__ = ["write_sweep", "findings_markdown"]

#: "Within" threshold of the report: vehicle 1's observer MSE <= THRESHOLD x Algorithm 1's.
THRESHOLD = 1.25


def _gammas(values) -> str:
    """Comma-separated values in ``%g`` format."""
    return ", ".join(f"{g:g}" for g in values)


def _pm(value: float, se: float) -> str:
    """``value +- se`` with a verdict against 1 (or no SE with one run)."""
    if se != se:  # NaN: a single run
        return f"{value:.3g} (one run: no standard error)"
    verdict = ("not distinguishable from 1 at two standard errors" if abs(value - 1.0) <= 2 * se
               else "Algorithm 1 better" if value < 1 else "Algorithm 1 worse")
    return f"{value:.3g} +- {se:.2g} (SE; {verdict})"


def _sentence(f: SweepFinding) -> str:
    """One factual bullet for one (noise, uncertainty) pair."""
    t = f.threshold
    text = f"- Noise {f.sensor_noise_std:g} m/s^2, uncertainty {100 * f.parameter_uncertainty:g} %: "
    if not f.gammas_algorithm1_wins:
        text += f"Algorithm 1 beats vehicle 1's observer by more than {t:g}x at no swept gamma. "
    elif f.wins_only_for_weak_observers:
        text += (f"Algorithm 1 beats vehicle 1's observer by more than {t:g}x at gamma = "
                 f"{_gammas(f.gammas_algorithm1_wins)}, not at the strongest swept observer "
                 f"(gamma = {f.largest_gamma:g}). ")
    else:
        text += (f"Algorithm 1 beats vehicle 1's observer by more than {t:g}x at gamma = "
                 f"{_gammas(f.gammas_algorithm1_wins)}, including the strongest swept observer. ")
    if f.smallest_gamma_within is None:
        text += f"The observer is within {t:g}x of Algorithm 1 at no swept gamma. "
    else:
        text += f"The observer is within {t:g}x of Algorithm 1 from gamma = {f.smallest_gamma_within:g}"
        if f.smallest_gamma_within != f.largest_gamma:
            text += " on" if f.within_at_every_larger_gamma else " (but not at every larger gamma)"
        text += ". "
    if f.unresolved_gammas:
        text += (f"At gamma = {_gammas(f.unresolved_gammas)} the gain is within two standard errors of {t:g}x, so "
                 f"the classification there is not resolved by these runs. ")
    return text + (f"At gamma = {f.largest_gamma:g}: Algorithm 1 / observer = "
                   f"{_pm(f.algorithm1_over_observer_at_largest, f.algorithm1_over_observer_at_largest_se)}; "
                   f"Algorithm 1 / own online observer (same vehicles 2..V) = "
                   f"{_pm(f.algorithm1_over_own_observer_at_largest, f.algorithm1_over_own_observer_at_largest_se)}; "
                   f"Algorithm 1 / own offline inversion (same vehicles 2..V) = "
                   f"{_pm(f.algorithm1_over_own_inversion_at_largest, f.algorithm1_over_own_inversion_at_largest_se)}.")


def _overall(findings: list[SweepFinding]) -> str:
    """One plain sentence over all pairs."""
    n, t = len(findings), findings[0].threshold
    weak = [f for f in findings if f.wins_only_for_weak_observers]
    never = [f for f in findings if not f.gammas_algorithm1_wins]
    if len(weak) == n:
        return (f"**In all {n} (noise, uncertainty) pairs, Algorithm 1 beats the single vehicle's own observer by more "
                f"than {t:g}x only for weak observers: at the strongest swept observer "
                f"(gamma = {findings[0].largest_gamma:g}) the single vehicle is within {t:g}x.**")
    if len(never) == n:
        return (f"**In none of the {n} (noise, uncertainty) pairs does Algorithm 1 beat the single vehicle's own "
                f"observer by more than {t:g}x.**")
    strong = [f for f in findings if f.gammas_algorithm1_wins and not f.wins_only_for_weak_observers]
    parts = [f"{text} in {len(group)} of {n} (noise, uncertainty) pairs" for text, group in (
        ("only for weak observers", weak),
        (f"including at the strongest swept observer (gamma = {findings[0].largest_gamma:g})", strong),
        ("at no swept gamma", never)) if group]
    return (f"**Algorithm 1 beats the single vehicle's own observer by more than {t:g}x "
            + "; ".join(parts) + ".**")


def findings_markdown(findings: list[SweepFinding]) -> str:
    """The answer section of the report: an overall sentence, a summary table and one bullet per pair.

    Parameters
    ----------
    findings : list of SweepFinding
        From :meth:`roadcollab.experiments.sweep.study.SweepResult.findings`.

    Returns
    -------
    str
        Markdown, without a trailing newline.
    """
    rows = [{"noise": f.sensor_noise_std, "uncertainty": f.parameter_uncertainty,
             "within": "none" if f.smallest_gamma_within is None else f.smallest_gamma_within,
             "ratio": f.algorithm1_over_observer_at_largest, "ratio_se": f.algorithm1_over_observer_at_largest_se,
             "obs": f.algorithm1_over_own_observer_at_largest, "obs_se": f.algorithm1_over_own_observer_at_largest_se,
             "own": f.algorithm1_over_own_inversion_at_largest, "own_se": f.algorithm1_over_own_inversion_at_largest_se}
            for f in findings]
    g_max, t = findings[0].largest_gamma, findings[0].threshold
    table = markdown_table(rows, ["noise", "uncertainty", "within", "ratio", "ratio_se", "obs", "obs_se", "own",
                                  "own_se"], [
        "sensor noise (m/s^2)", "parameter uncertainty", f"smallest gamma with observer within {t:g}x",
        f"Algorithm 1 / vehicle 1 observer at gamma = {g_max:g}", "SE",
        f"Algorithm 1 / own observer (vehicles 2..V) at gamma = {g_max:g}", "SE",
        f"Algorithm 1 / own inversion (vehicles 2..V) at gamma = {g_max:g}", "SE"])
    return "\n".join([_overall(findings), "", table, "", *(_sentence(f) for f in findings)])


#: ``sweep.csv`` columns shown in the report's table, with their headers (``{V}``: the fleet size).
_TABLE_COLUMNS = [("gamma", "gamma"), ("sensor_noise_std", "noise (m/s^2)"),
                  ("parameter_uncertainty", "uncertainty"), ("vehicle1_observer_mse", "vehicle 1 observer"),
                  ("algorithm1_mse", "Algorithm 1 (2..V)"), ("algorithm1_mse_se", "SE"),
                  ("algorithm1_gain", "gain"), ("algorithm1_gain_se", "gain SE"),
                  ("observer_only_mse", "own observer (all)"), ("own_inversion_mse", "own inversion"),
                  ("own_posterior_inversion_mse", "own posterior inv."), ("fused_mse", "fused (vehicle {V})"),
                  ("fused_posterior_mse", "fused posterior (vehicle {V})"),
                  ("centralized_mse", "centralized (vehicle {V})"), ("oracle_per_bin_mse", "per-bin oracle (vehicle {V})")]


def _intro_lines(result: SweepResult, n_rows: int, command: str, elapsed: float) -> list[str]:
    """Title, the grid, the run description and how grid points are paired."""
    cfg, exp = result.config, result.config.experiment
    road = exp.road_profile or f"synthetic ISO 8608 class {exp.iso_class}"
    return [
        "# roadcollab sweep: where Algorithm 1 beats a single vehicle",
        "",
        f"Command: `{command}`  ",
        f"Seed {result.seed}; {n_rows} grid points (gamma {_gammas(cfg.gammas)} x sensor noise "
        f"{_gammas(cfg.sensor_noise_stds)} m/s^2 x parameter uncertainty "
        f"{', '.join(f'{100 * u:g} %' for u in cfg.parameter_uncertainties)}); "
        f"{plural(cfg.n_runs, 'run')} per grid point, each with a new fleet of {cfg.n_vehicles} vehicles and its own "
        f"road; {elapsed:.1f} s.  ",
        f"Road: {road}; speed {exp.speed:g} m/s; {exp.sample_rate:g} Hz; scored segment {exp.segment_length:g} m "
        f"(+{exp.margin:g} m lead-in/out); fleet spread +-{100 * exp.fleet.spread:g} %; band from "
        f"{exp.band_low_hz:g} Hz.",
        "",
        "Run r uses the same road, the same standard-normal sensor noise (scaled by the noise level) and the same "
        "fleet draw (parameter-estimate errors scaled by the uncertainty) at every grid point, so grid points are "
        "paired comparisons (common random numbers).",
        "",
    ]


def _answer_lines(findings: list[SweepFinding], n_vehicles: int) -> list[str]:
    """What "within" and "beats" mean, then the findings and the figure."""
    return [
        "## Answer",
        "",
        f"The single vehicle is vehicle 1 with its own online observer (eq. 4). \"Within {THRESHOLD:g}x\" means its "
        f"MSE is at most {THRESHOLD:g} times Algorithm 1's (averaged over vehicles 2..{n_vehicles}); \"beats by more "
        f"than {THRESHOLD:g}x\" is the opposite. Ratios below 1 favour Algorithm 1.",
        "",
        findings_markdown(findings),
        "",
        "![MSE vs gamma](sweep.png)",
        "",
    ]


def _table_lines(rows: list[SweepRow], n_vehicles: int) -> list[str]:
    """The report's copy of ``sweep.csv`` (the columns of :data:`_TABLE_COLUMNS`)."""
    return [
        "## Table (`sweep.csv`)",
        "",
        markdown_table(rows, [c for c, _ in _TABLE_COLUMNS], [h.format(V=n_vehicles) for _, h in _TABLE_COLUMNS]),
        "",
    ]


def _definition_lines(n_vehicles: int, n_runs: int) -> list[str]:
    """What every column means and how its standard error is computed."""
    V, R = n_vehicles, n_runs
    return [
        "## Definitions",
        "",
        "MSE: mean square of the band-limited road-velocity error over the scored segment and both tracks, "
        "(m/s)^2, averaged over runs.",
        "",
        "- `vehicle1_observer_mse`: vehicle 1's own observer (nobody drove ahead of it).",
        f"- `algorithm1_mse`: Algorithm 1, averaged over vehicles 2..{V}.",
        f"- `own_inversion_mse`: each vehicle's offline inversion of its own record, averaged over all {V} vehicles "
        "(it does not depend on gamma).",
        f"- `fused_mse`, `centralized_mse`, `oracle_per_bin_mse`: at vehicle {V}, from the records of vehicles 1..{V}; "
        "the per-bin oracle is the linear MMSE with the true models per bin of the padded grid.",
        "- `algorithm1_gain` = `vehicle1_observer_mse / algorithm1_mse` (> 1: Algorithm 1 better).",
        "- Standard errors are over runs, which are independent (new fleet and road each): `algorithm1_mse_se` of the "
        f"per-run means over vehicles 2..{V}; `algorithm1_gain_se` by the delta method on the paired per-run values "
        f"(first order; with {plural(R, 'run')} an approximation).",
        "",
    ]


def write_sweep(result: SweepResult, out, *, command: str, elapsed: float) -> list[SweepFinding]:
    """Write every output of ``roadcollab sweep`` to the folder ``out``.

    Files: ``sweep.csv`` (one row per grid point, :class:`~roadcollab.experiments.sweep.study.SweepRow` columns),
    ``sweep.png`` (the figure of that CSV), ``config.json`` and ``report.md``.

    Parameters
    ----------
    result : SweepResult
        The sweep to report.
    out : str or Path
        Output folder (created if missing; files overwritten).
    command : str
        The command line, recorded in ``config.json`` and the report.
    elapsed : float
        Wall-clock time of the sweep, s.

    Returns
    -------
    list of SweepFinding
        The findings the report states (threshold :data:`THRESHOLD`).
    """
    out = output_dir(out)
    cfg = result.config
    rows = result.table()
    write_rows(out / "sweep.csv", rows, SweepRow)
    plot_sweep(rows, out / "sweep.png")
    findings = result.findings(threshold=THRESHOLD)
    write_config(out / "config.json", command=command, seed=result.seed, config=cfg.to_dict(),
                 extra={"elapsed_s": elapsed, "n_grid_points": len(rows),
                        "findings": [dataclasses.asdict(f) for f in findings]})
    lines = (_intro_lines(result, len(rows), command, elapsed) + _answer_lines(findings, cfg.n_vehicles)
             + _table_lines(rows, cfg.n_vehicles) + _definition_lines(cfg.n_vehicles, cfg.n_runs))
    (out / "report.md").write_text("\n".join(lines))
    return findings
