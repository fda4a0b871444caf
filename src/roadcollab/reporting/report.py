"""Run records: CSV for every plotted number, config.json, and a Markdown report.

Every run writes its seed, full configuration and the package version next to its outputs.
"""

from __future__ import annotations

import csv
import json
import platform
import sys
from pathlib import Path

import numpy as np

__all__ = ["write_csv", "write_config", "markdown_table", "fmt"]


def _plain(value):
    """JSON-ready version of numpy scalars, arrays, tuples and paths."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    return value


def fmt(value) -> str:
    """Compact number formatting for CSV and tables (4 significant digits)."""
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.4g}"
    return str(value)


def write_csv(path, rows: list[dict], columns: list[str] | None = None) -> Path:
    """Write dict rows to CSV with full float precision (repr).

    Parameters
    ----------
    path : str or Path
        Output file (overwritten).
    rows : list of dict
        One dict per row, holding every key of ``columns``. Python and numpy floats are written
        as ``repr(float(v))``, other values as ``str(v)``.
    columns : list of str, optional
        Column order and header (default: the keys of the first row; none if ``rows`` is empty).

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    columns = columns or list(rows[0].keys()) if rows else (columns or [])
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for r in rows:
            w.writerow([repr(float(r[c])) if isinstance(r[c], (float, np.floating)) else r[c] for c in columns])
    return path


def write_config(path, *, command: str, seed: int | None, config: dict, extra: dict | None = None) -> Path:
    """Write ``config.json``: command, seed, configuration, package and platform versions.

    Parameters
    ----------
    path : str or Path
        Output file (overwritten).
    command : str
        The command line of the run.
    seed : int or None
        Root seed (None if the run has none).
    config : dict
        Full configuration; numpy scalars and arrays, tuples and paths become JSON types.
    extra : dict, optional
        More top-level keys, converted the same way (they replace standard keys of the same name).

    Returns
    -------
    Path
        ``path``.
    """
    from .. import __version__

    record = {
        "command": command,
        "seed": seed,
        "roadcollab_version": __version__,
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "platform": platform.platform(),
        "config": config,
    }
    if extra:
        record.update(extra)
    path = Path(path)
    path.write_text(json.dumps(_plain(record), indent=2) + "\n")
    return path


def markdown_table(rows: list[dict], columns: list[str], headers: list[str] | None = None) -> str:
    """A GitHub-flavoured Markdown table.

    Parameters
    ----------
    rows : list of dict
        One dict per table row, holding every key of ``columns``.
    columns : list of str
        Keys shown, in order; values formatted by :func:`fmt` (numbers to 4 significant digits).
    headers : list of str, optional
        Header text of each column (default: ``columns``).

    Returns
    -------
    str
        The table, one line per row, without a trailing newline.
    """
    headers = headers or columns
    out = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    for r in rows:
        out.append("| " + " | ".join(fmt(r[c]) for c in columns) + " |")
    return "\n".join(out)


MSE_COLUMNS = ["vehicle", "mse_mean", "mse_std", "mse_no_privacy_mean", "observer_only_mse_mean",
               "observer_only_mse_std", "own_inversion_mse_mean", "own_posterior_inversion_mse_mean", "fused_mse_mean",
               "fused_posterior_mse_mean",
               "centralized_mse_mean", "oracle_bound_mse_mean", "nmse_mean", "observer_only_nmse_mean", "own_inversion_nmse_mean",
               "own_posterior_inversion_nmse_mean", "fused_nmse_mean", "fused_posterior_nmse_mean", "centralized_nmse_mean", "oracle_bound_nmse_mean", "max_rel_diff_privacy",
               "theorem1_e_max", "theorem1_wf_max", "theorem1_e_band_max", "theorem1_wf_band_max"]
BOUND_COLUMNS = ["estimator", "vehicle", "mean_excess", "stderr", "z"]
#: Columns of the headline table in the report: (column, header).
HEADLINE_COLUMNS = [("vehicle", "vehicle"), ("observer_only_mse_mean", "observer only"),
             ("own_inversion_mse_mean", "own inversion"), ("own_posterior_inversion_mse_mean", "own posterior inv."),
             ("mse_mean", "Alg. 1+2"),
             ("mse_no_privacy_mean", "Alg. 1"), ("fused_mse_mean", "fused"),
                    ("fused_posterior_mse_mean", "fused (posterior)"), ("centralized_mse_mean", "centralized"),
             ("oracle_bound_mse_mean", "oracle bound"), ("max_rel_diff_privacy", "max rel diff privacy")]


def reproduction_summary(rows: list[dict], bound_rows: list[dict] | None = None) -> dict:
    """Headline numbers of a reproduction (used by the report and the CLI).

    Parameters
    ----------
    rows : list of dict
        :meth:`~roadcollab.experiments.reproduction.ReproductionResult.table` rows.
    bound_rows : list of dict, optional
        :meth:`~roadcollab.experiments.reproduction.ReproductionResult.bound_check` rows.

    Returns
    -------
    dict
        Ratios of MSEs (dimensionless) and exactness figures.
    """
    V = len(rows)
    v1 = rows[0]
    later = rows[1:]
    mean = lambda key, rs: float(np.mean([r[key] for r in rs])) if rs else float("nan")  # noqa: E731
    k5 = min(5, V) - 1
    out = {
        "vehicle1_observer_mse": v1["observer_only_mse_mean"],
        "vehicle1_observer_over_own_inversion": v1["observer_only_mse_mean"] / v1["own_inversion_mse_mean"],
        "algorithm1_mean_mse": mean("mse_mean", later),
        "vehicle1_observer_over_algorithm1": v1["observer_only_mse_mean"] / mean("mse_mean", later),
        "observer_over_algorithm1_same_vehicles": mean("observer_only_mse_mean", later) / mean("mse_mean", later),
        "own_inversion_over_algorithm1_same_vehicles": mean("own_inversion_mse_mean", later) / mean("mse_mean", later),
        "own_posterior_inversion_over_algorithm1_same_vehicles":
            mean("own_posterior_inversion_mse_mean", later) / mean("mse_mean", later),
        "max_rel_diff_privacy": max(r["max_rel_diff_privacy"] for r in rows),
        "theorem1_e_max": max(r["theorem1_e_max"] for r in rows),
        "theorem1_wf_max": max(r["theorem1_wf_max"] for r in rows),
        "theorem1_e_band_max": max(r["theorem1_e_band_max"] for r in rows),
        "theorem1_wf_band_max": max(r["theorem1_wf_band_max"] for r in rows),
        "fused_over_centralized_last": rows[-1]["fused_mse_mean"] / rows[-1]["centralized_mse_mean"],
        "algorithm1_over_fused_last": rows[-1]["mse_mean"] / rows[-1]["fused_mse_mean"],
        "fused_posterior_over_centralized_last": rows[-1]["fused_posterior_mse_mean"] / rows[-1]["centralized_mse_mean"],
        "algorithm1_over_fused_posterior_last": rows[-1]["mse_mean"] / rows[-1]["fused_posterior_mse_mean"],
        "vehicle1_observer_over_fused5": v1["observer_only_mse_mean"] / rows[k5]["fused_mse_mean"],
        "vehicle1_observer_over_fused_posterior5": v1["observer_only_mse_mean"] / rows[k5]["fused_posterior_mse_mean"],
        "fused5_vehicles": k5 + 1,
        "oracle_over_fused_last": rows[-1]["oracle_bound_mse_mean"] / rows[-1]["fused_mse_mean"],
    }
    if bound_rows:
        worst = min(bound_rows, key=lambda r: r["z"])
        out.update(bound_min_z=worst["z"], bound_min_z_estimator=worst["estimator"],
                   bound_min_z_vehicle=worst["vehicle"], bound_beaten=bool(worst["z"] < -3))
    return out


def _ratio_words(ratio: float) -> str:
    """``other / this`` as "2.1x better" or "2.1x worse"."""
    return f"{ratio:.2f}x better" if ratio >= 1 else f"{1 / ratio:.2f}x worse"


def _summary_lines(summary: dict, n_vehicles: int) -> list[str]:
    """The report's summary bullets, worded from the numbers."""
    s = summary
    return [
        f"- Vehicle 1's lag-free online estimate (observer only) has MSE {s['vehicle1_observer_mse']:.4g}, "
        f"{s['vehicle1_observer_over_own_inversion']:.2f}x its own offline inversion.",
        f"- Algorithm 1 (vehicles 2..{n_vehicles}, mean MSE {s['algorithm1_mean_mse']:.4g}) is "
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
        f"{s['algorithm1_over_fused_last']:.1f}x better than Algorithm 1; the oracle bound is "
        f"{1 / s['oracle_over_fused_last']:.0f}x below it. Fused from posterior inversions: "
        f"{s['fused_posterior_over_centralized_last']:.2f}x the centralized MMSE and "
        f"{s['algorithm1_over_fused_posterior_last']:.1f}x better than Algorithm 1.",
        f"- The fused estimate of {s['fused5_vehicles']} vehicles is "
        f"{_ratio_words(s['vehicle1_observer_over_fused5'])} (posterior: "
        f"{_ratio_words(s['vehicle1_observer_over_fused_posterior5'])}) than vehicle 1's online estimate.",
    ] + ([
        "- Oracle bound: " + ("**beaten** " if s["bound_beaten"] else "not beaten ")
        + f"(smallest paired z-score of any estimator's excess MSE over the bound: {s['bound_min_z']:.1f}, "
        f"{s['bound_min_z_estimator']} at vehicle {s['bound_min_z_vehicle']}; beaten means z < -3)."]
        if "bound_min_z" in s else [])


def write_reproduction(result, out, *, command: str, elapsed: float, measured=None) -> dict:
    """Write every output of ``roadcollab reproduce`` to the folder ``out``.

    Files: ``mse.csv``, ``fig4_mse.png`` (+ ``fig4_mse.csv`` = mse.csv),
    ``fig5..7_vehicle{1..3}.png`` with their CSVs, ``fig_fusion.png``, ``fleet.csv``,
    ``config.json`` and ``report.md``.
    """
    from ..reporting import plotting

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = result.config
    rows = result.table()
    bound = result.bound_check()
    write_csv(out / "mse.csv", rows, MSE_COLUMNS)
    write_csv(out / "bound_check.csv", bound, BOUND_COLUMNS)
    plotting.plot_mse(rows, out / "fig4_mse.png")
    plotting.plot_fusion(rows, out / "fig_fusion.png")
    tr = result.runs[0].traces
    figs = []
    for j in range(min(3, len(tr["plain"]))):
        name = f"fig{5 + j}_vehicle{j + 1}"
        t = tr["time"]
        write_csv(out / f"{name}.csv", [
            {"time_s": float(t[k]), "actual_left": tr["truth"][k, 0], "actual_right": tr["truth"][k, 1],
             "no_privacy_left": tr["plain"][j][k, 0], "no_privacy_right": tr["plain"][j][k, 1],
             "privacy_left": tr["private"][j][k, 0], "privacy_right": tr["private"][j][k, 1]}
            for k in range(t.size)])
        t0 = float(t[0])
        plotting.plot_estimates(t, tr["truth"], tr["plain"][j], tr["private"][j], j + 1, out / f"{name}.png",
                                window=(t0 + 5.0, t0 + 8.0))
        figs.append(name)
    fleet_rows = []
    for v in result.fleet:
        row = {"vehicle": v.index + 1}
        row.update({f"true_{k}": x for k, x in v.true_params.as_dict().items()})
        row.update({f"estimated_{k}": x for k, x in v.estimated_params.as_dict().items()})
        fleet_rows.append(row)
    write_csv(out / "fleet.csv", fleet_rows)
    summary = reproduction_summary(rows, bound)
    write_config(out / "config.json", command=command, seed=result.seed, config=cfg.to_dict(),
                 extra={"elapsed_s": elapsed, "summary": summary})
    road = cfg.road_profile or f"synthetic ISO 8608 class {cfg.iso_class}"
    lines = [
        "# roadcollab reproduction: collaborative estimation with privacy (Figs. 4-7)",
        "",
        f"Command: `{command}`  ",
        f"Seed {result.seed}; {cfg.n_runs} runs x {cfg.n_vehicles} vehicles; {elapsed:.1f} s.  ",
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
        "sensor noise); *oracle bound* = the linear MMSE with the true models (no estimator here can beat it on "
        "average; `bound_check.csv` tests that).",
        "",
        "## Summary",
        "",
        *_summary_lines(summary, cfg.n_vehicles),
        "",
        "## MSE per vehicle (`mse.csv`, (m/s)^2)",
        "",
        markdown_table(rows, [c for c, _ in HEADLINE_COLUMNS], [h for _, h in HEADLINE_COLUMNS]),
        "",
        "## Fig. 4: MSE per vehicle",
        "",
        "![Fig. 4](fig4_mse.png)",
        "",
        "## Fused, centralized and oracle estimates",
        "",
        "![fusion](fig_fusion.png)",
        "",
        "## Figs. 5-7: actual road input vs estimates with and without privacy (run 1, a 3 s window)",
        "",
    ]
    for j, name in enumerate(figs):
        lines += [f"![Vehicle {j + 1}]({name}.png)", ""]
    if measured is not None:
        mres, mel = measured
        mrows = mres.table()
        write_csv(out / "mse_measured.csv", mrows, MSE_COLUMNS)
        plotting.plot_fusion(mrows, out / "fig_measured_mse.png")
        ms = reproduction_summary(mrows, mres.bound_check())
        mc = mres.config
        lines += [
            "## Measured road profile (shipped with the package)",
            "",
            f"`profile_1.txt` (MIT licence beside it): one measured track; the second track is the measured one plus "
            f"an independent ISO class A residual high-passed at 20 m. {mc.n_runs} runs, same fleet and seed, speed "
            f"{mc.speed:g} m/s, scored {mc.segment_length:g} m; {mel:.1f} s. The online estimators are still designed "
            f"for an ISO class {mc.iso_class} road; the linear MMSE estimates use the measured road's own spectrum.",
            "",
            *_summary_lines(ms, mc.n_vehicles),
            "",
            markdown_table(mrows, [c for c, _ in HEADLINE_COLUMNS], [h for _, h in HEADLINE_COLUMNS]),
            "",
            "![measured](fig_measured_mse.png)",
            "",
        ]
    lines += ["## Fleet (`fleet.csv`)", "",
              markdown_table(fleet_rows, ["vehicle", "true_sprung_mass", "estimated_sprung_mass", "true_stiffness",
                                          "estimated_stiffness", "true_damping", "estimated_damping"]), ""]
    (out / "report.md").write_text("\n".join(lines))
    return summary


ATTACK_COLUMNS = ["mechanism", "attack", "median_rel_pole_error", "success_rate", "n_messages"]
BASELINE_COLUMNS = ["mechanism", "mse_vehicle1", "mse_vehicle2", "mse_vehicle3", "ms_per_message",
                    "bytes_per_message", "note"]


def security_markdown(result) -> str:
    """The security section of a report (attacks, exactness, linkability, baselines)."""
    cfg = result.config
    lines = [
        "## Security",
        "",
        f"{cfg.n_runs} segments x {cfg.experiment.n_vehicles} vehicles; seed {result.seed}. The target is the "
        "four poles of S_j = -P_hat_j (the vehicle's suspension model). An attack succeeds on a message when "
        "every pole is recovered within 1 % relative error after Hungarian matching. Against the hardened "
        "exchange (z only) each attack works from signals and is *given the true road*. `no_message / "
        "prior_guess` is what the attacker knows without any message (the fleet's nominal poles).",
        "",
        "### Attacks (`attack.csv`)",
        "",
        markdown_table(result.attack_rows, ATTACK_COLUMNS),
        "",
        "![attack success](fig11_attack_success.png)",
        "",
        "### Figs. 8-10: poles of S_1..S_3 and the attackers' estimates (paper's mechanism, run 1)",
        "",
    ]
    for ex in result.pole_examples:
        lines += [f"![Vehicle {ex['vehicle']}](fig{7 + ex['vehicle']}_poles_vehicle{ex['vehicle']}.png)", ""]
    lines += [
        "### Exactness (`exactness.csv`): largest relative change of any estimate vs. no privacy",
        "",
        markdown_table(result.exactness_rows, ["mechanism", "max_rel_diff"]),
        "",
        "### Linkability (`linkability.csv`): can messages of one vehicle be linked across segments?",
        "",
        "AUC = probability that two messages of the same vehicle (different segments) are closer in the "
        "feature than two messages of different vehicles (0.5 = no information); top-1 = how often the "
        "nearest message from another segment is the same vehicle's.",
        "",
        markdown_table(result.linkability_rows, ["mechanism", "feature", "auc", "top1_accuracy", "chance"]),
        "",
        "### Baselines on the same segments (`baselines.csv`)",
        "",
        markdown_table(result.baseline_rows, BASELINE_COLUMNS),
        "",
    ]
    return "\n".join(lines)


def write_attack(result, out, *, command: str, elapsed: float) -> None:
    """Write every output of ``roadcollab attack`` to ``out``."""
    from ..reporting import plotting

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "attack.csv", result.attack_rows, ATTACK_COLUMNS)
    write_csv(out / "exactness.csv", result.exactness_rows, ["mechanism", "max_rel_diff"])
    write_csv(out / "linkability.csv", result.linkability_rows,
              ["mechanism", "feature", "auc", "top1_accuracy", "chance"])
    write_csv(out / "baselines.csv", result.baseline_rows, BASELINE_COLUMNS)
    plotting.plot_attack_success(result.attack_rows, out / "fig11_attack_success.png")
    pole_rows = []
    for ex in result.pole_examples:
        plotting.plot_poles(ex, out / f"fig{7 + ex['vehicle']}_poles_vehicle{ex['vehicle']}.png")
        for key in ("true", "model_reduction", "pole_intersection", "multiplicity"):
            for p in np.asarray(ex[key]):
                pole_rows.append({"vehicle": ex["vehicle"], "kind": key, "real": float(p.real), "imag": float(p.imag)})
    write_csv(out / "fig8_10_poles.csv", pole_rows, ["vehicle", "kind", "real", "imag"])
    write_config(out / "config.json", command=command, seed=result.seed, config=result.config.to_dict(),
                 extra={"elapsed_s": elapsed})
    text = ["# roadcollab attack: how much privacy the exchanges give", "", f"Command: `{command}`  ",
            f"{elapsed:.1f} s.", "", security_markdown(result)]
    (out / "report.md").write_text("\n".join(text))


DETECTION_COLUMNS = ["estimator", "precision", "recall", "f1", "median_position_error_m", "median_depth_rel_error",
                     "kind_accuracy", "side_accuracy", "n_true", "n_detected", "n_matched"]


def anomaly_markdown(result) -> str:
    """The anomaly-detection section of a report."""
    cfg = result.config
    exp = cfg.experiment
    road = (f"measured profile `{exp.road_profile}` with synthetic anomalies" if exp.road_profile
            else f"synthetic ISO 8608 class {exp.iso_class}")
    lines = [
        "## Road anomaly detection",
        "",
        f"{cfg.n_runs} runs, seed {result.seed}; road: {road}; {exp.speed:g} m/s; sensor noise "
        f"{exp.sensor_noise_std:g} m/s^2; vehicles 2..{exp.n_vehicles} pooled; a detection matches a true anomaly "
        f"within {cfg.tolerance:g} m (center to center) on a shared track.",
        "",
        "### Detection (`detection.csv`)",
        "",
        markdown_table(result.detection_rows, DETECTION_COLUMNS),
        "",
        "![road map](fig_anomaly_map.png)",
        "",
    ]
    if result.depth_rows:
        lines += ["### F1 vs anomaly depth (`f1_vs_depth.csv`)", "",
                  markdown_table(result.depth_rows, ["depth_m", "estimator", "precision", "recall", "f1",
                                                     "median_position_error_m"]), "",
                  "![F1 vs depth](fig_f1_vs_depth.png)", ""]
    if result.noise_rows:
        lines += ["### F1 vs sensor noise (`f1_vs_noise.csv`)", "",
                  markdown_table(result.noise_rows, ["sensor_noise_std", "estimator", "precision", "recall", "f1",
                                                     "median_position_error_m"]), "",
                  "![F1 vs noise](fig_f1_vs_noise.png)", ""]
    return "\n".join(lines)


def write_anomalies(result, out, *, command: str, elapsed: float) -> None:
    """Write every output of ``roadcollab anomalies`` to ``out``."""
    from ..reporting import plotting

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "detection.csv", result.detection_rows, DETECTION_COLUMNS)
    write_csv(out / "detection_per_vehicle.csv", result.vehicle_rows, ["vehicle"] + DETECTION_COLUMNS)
    plotting.plot_anomaly_map(result.map_example, out / "fig_anomaly_map.png")
    rows = []
    for t in result.map_example["truth"]:
        rows.append({"source": "truth", "estimator": "", "position_m": t["center"], "side": t["side"],
                     "kind": t["kind"], "depth_m": t["depth"], "confidence": 1.0})
    for name, dets in result.map_example["detections"].items():
        for d in dets:
            rows.append({"source": "detected", "estimator": name, "position_m": d["position"], "side": d["side"],
                         "kind": d["kind"], "depth_m": d["depth"], "confidence": d["confidence"]})
    write_csv(out / "fig_anomaly_map.csv", rows,
              ["source", "estimator", "position_m", "side", "kind", "depth_m", "confidence"])
    if result.depth_rows:
        write_csv(out / "f1_vs_depth.csv", result.depth_rows, ["depth_m"] + DETECTION_COLUMNS)
        plotting.plot_f1_vs_depth(result.depth_rows, out / "fig_f1_vs_depth.png")
    if result.noise_rows:
        write_csv(out / "f1_vs_noise.csv", result.noise_rows, ["sensor_noise_std"] + DETECTION_COLUMNS)
        plotting.plot_f1_vs_noise(result.noise_rows, out / "fig_f1_vs_noise.png")
    write_config(out / "config.json", command=command, seed=result.seed, config=result.config.to_dict(),
                 extra={"elapsed_s": elapsed})
    (out / "report.md").write_text("\n".join([
        "# roadcollab anomalies: detecting potholes and bumps from the estimates", "",
        f"Command: `{command}`  ", f"{elapsed:.1f} s.", "", anomaly_markdown(result)]))
