"""Report of the anomaly detector's calibration: ``calibration.csv``, ``config.json``, ``report.md``."""

from __future__ import annotations

from pathlib import Path

from ..experiments.anomalies.config import ESTIMATORS
from ..experiments.anomalies.calibration_config import EVALUATION_SEEDS, OBJECTIVE_ESTIMATORS
from ..experiments.anomalies.calibration_result import AnomalyCalibrationResult, score_column
from .records import fmt, markdown_table, write_config, write_csv
from .wording import plural

__all__ = ["calibration_markdown", "write_calibration"]


def _flatness_lines(result: AnomalyCalibrationResult) -> list[str]:
    """Markdown lines on how flat the optimum is: points near the best, and the objective grid."""
    cfg, best, n = result.config, result.best, len(result.points)
    gaps = [result.gap(p) for p in result.points]
    lines = []
    for tol in (0.002, 0.005, 0.01, 0.02):
        near = [p for p, (gap, _) in zip(result.points, gaps) if gap <= tol]
        lines.append(f"- within {tol:g} of the best objective: {len(near)} of {n} points"
                     + (": " + ", ".join(f"({p.snr_threshold:g}, {1000 * p.min_depth:g} mm)" for p in near)
                        if len(near) <= 8 else ""))
    if len(cfg.seeds) > 1:
        tied = [p for p, (gap, se) in zip(result.points, gaps) if gap <= 2 * se or p is best]
        lines.append(f"- within two paired standard errors (over the {plural(len(cfg.seeds), 'seed')}) of the best: "
                     f"{len(tied)} of {n} points: "
                     + ", ".join(f"({p.snr_threshold:g}, {1000 * p.min_depth:g} mm)" for p in tied))
    obj = [p.objective for p in result.points]
    lines.append(f"- objective range over the grid: {fmt(min(obj))} to {fmt(max(obj))}")
    lines += ["", "Objective (rows `snr_threshold`, columns `min_depth`):", "",
              "| snr_threshold | " + " | ".join(f"{1000 * d:g} mm" for d in cfg.min_depths) + " |",
              "|---|" + "---|" * len(cfg.min_depths)]
    it = iter(result.points)
    for t in cfg.snr_thresholds:
        cells = [next(it) for _ in cfg.min_depths]
        lines.append(f"| {t:g} | " + " | ".join(
            f"**{fmt(p.objective)}**" if p is best else fmt(p.objective) for p in cells) + " |")
    return lines


def calibration_markdown(result: AnomalyCalibrationResult) -> str:
    """The body of the calibration report (best point, flatness, per-point table).

    Parameters
    ----------
    result : AnomalyCalibrationResult

    Returns
    -------
    str
        Markdown, ending in a newline.
    """
    cfg, best = result.config, result.best
    exp = cfg.experiment
    contiguous = len(cfg.seeds) > 1 and cfg.seeds == tuple(range(cfg.seeds[0], cfg.seeds[-1] + 1))
    seeds = f"{cfg.seeds[0]}..{cfg.seeds[-1]}" if contiguous else ", ".join(map(str, cfg.seeds))
    lo, hi = exp.road_spec().depth_range
    conds = ", ".join([f"default road (anomalies {100 * lo:g}-{100 * hi:g} cm)"]
                      + [f"every anomaly {100 * d:g} cm" for d in cfg.condition_depths])
    lines = [
        f"Training seeds {seeds} (never the evaluation seeds {list(EVALUATION_SEEDS)}), "
        f"{plural(cfg.runs_per_seed, 'run')} each; {exp.n_vehicles} vehicles, ISO class {exp.iso_class}, "
        f"{exp.speed:g} m/s, sensor noise "
        f"{exp.sensor_noise_std:g} m/s^2; conditions: {conds}; vehicles 2..{exp.n_vehicles} pooled; a detection "
        f"matches within {cfg.tolerance:g} m. Objective: mean F1 of {' and '.join(OBJECTIVE_ESTIMATORS)} over "
        f"the conditions.",
        "",
        "## Best point",
        "",
        f"Best point: snr_threshold = {best.snr_threshold:g}, min_depth = {best.min_depth:g} m "
        f"(objective {fmt(best.objective)}).",
        "",
    ]
    ref = result.reference
    det = f"The configured detector ({cfg.detector.snr_threshold:g}, {1000 * cfg.detector.min_depth:g} mm)"
    if ref is None:
        lines.append(f"{det} is not on the grid.")
    elif ref is best:
        lines.append(f"{det} is the best point.")
    else:
        gap, se = result.gap(ref)
        lines.append(f"{det}: objective {fmt(ref.objective)}, {fmt(gap)} below the best (paired standard error "
                     f"over seeds {fmt(se)}).")
    lines += ["", "F1 of the best point:", "",
              markdown_table([{"condition": c, **{e: best.scores[c, e]["f1"] for e in ESTIMATORS}}
                              for c in cfg.conditions], ["condition", *ESTIMATORS]),
              "", "## Flatness of the optimum", "", *_flatness_lines(result), "",
              "## Every grid point (`calibration.csv`)", ""]
    cols = result.columns()[:5] + [score_column("f1", c, e) for c in cfg.conditions for e in OBJECTIVE_ESTIMATORS]
    lines.append(markdown_table([r.record() for r in result.to_rows()], cols))
    return "\n".join(lines) + "\n"


def write_calibration(result: AnomalyCalibrationResult, out, *, command: str) -> Path:
    """Write ``calibration.csv``, ``config.json`` and ``report.md`` of a calibration to ``out``.

    Parameters
    ----------
    result : AnomalyCalibrationResult
    out : str or Path
        Output folder (created if missing).
    command : str
        The command line of the run (recorded in config.json and the report).

    Returns
    -------
    Path
        ``out``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    # Columns depend on the conditions (CalibrationRow.scores): the list stays with the result.
    write_csv(out / "calibration.csv", [r.record() for r in result.to_rows()], result.columns())
    write_config(out / "config.json", command=command, seed=None, config=result.config.to_dict(),
                 extra={"seeds": list(result.config.seeds), "elapsed_s": result.elapsed_s})
    (out / "report.md").write_text("\n".join([
        "# roadcollab calibrate-anomalies: detector threshold and depth floor on training seeds", "",
        f"Command: `{command}`  ", f"{result.elapsed_s:.1f} s.", "", calibration_markdown(result)]))
    return out
