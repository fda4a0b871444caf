"""Outputs of ``roadcollab anomalies``: detection tables, the road map, F1 curves, ``config.json`` and ``report.md``."""

from __future__ import annotations

from pathlib import Path

from . import plotting
from ..experiments.anomalies.rows import (DepthDetectionRow, DetectionRow, MapRow, NoiseDetectionRow,
                                          VehicleDetectionRow)
from .records import markdown_table, output_dir, row_columns, run_header, write_config, write_rows
from .wording import plural

__all__ = ["anomaly_markdown", "write_anomalies"]

#: Fields of the F1 curves shown in the report, after the swept quantity.
_CURVE_REPORT_COLUMNS = ["estimator", "precision", "recall", "f1", "median_position_error_m"]


def _detection_lines(result) -> list[str]:
    """Run description, the detection table and the road map."""
    cfg = result.config
    exp = cfg.experiment
    road = (f"measured profile `{exp.road_profile}` with synthetic anomalies" if exp.road_profile
            else f"synthetic ISO 8608 class {exp.iso_class}")
    return [
        "## Road anomaly detection",
        "",
        f"{plural(cfg.n_runs, 'run')}, seed {result.seed}; road: {road}; {exp.speed:g} m/s; sensor noise "
        f"{exp.sensor_noise_std:g} m/s^2; vehicles 2..{exp.n_vehicles} pooled; a detection matches a true anomaly "
        f"within {cfg.tolerance:g} m (center to center) on a shared track.",
        "",
        "### Detection (`detection.csv`)",
        "",
        markdown_table(result.detection_rows, row_columns(DetectionRow)),
        "",
        "![road map](fig_anomaly_map.png)",
        "",
    ]


def _curve_lines(rows: list, key: str, what: str, name: str, alt: str) -> list[str]:
    """One F1 curve of the report: heading, table (``key`` first) and the figure ``fig_{name}.png``."""
    return [f"### F1 vs {what} (`{name}.csv`)", "",
            markdown_table(rows, [key] + _CURVE_REPORT_COLUMNS), "",
            f"![{alt}](fig_{name}.png)", ""]


def anomaly_markdown(result) -> str:
    """The anomaly-detection section of a report.

    Parameters
    ----------
    result : roadcollab.experiments.anomalies.study.AnomalyStudyResult
        The anomaly study.

    Returns
    -------
    str
        Markdown: detection table, road map and the F1 curves the study swept; ends with a newline.
    """
    lines = _detection_lines(result)
    if result.depth_rows:
        lines += _curve_lines(result.depth_rows, "depth_m", "anomaly depth", "f1_vs_depth", "F1 vs depth")
    if result.noise_rows:
        lines += _curve_lines(result.noise_rows, "sensor_noise_std", "sensor noise", "f1_vs_noise", "F1 vs noise")
    return "\n".join(lines)


def _write_curves(result, out: Path) -> None:
    """``f1_vs_depth`` and ``f1_vs_noise`` (CSV and figure) for the sweeps the study ran."""
    if result.depth_rows:
        write_rows(out / "f1_vs_depth.csv", result.depth_rows, DepthDetectionRow)
        plotting.plot_f1_vs_depth(result.depth_rows, out / "fig_f1_vs_depth.png")
    if result.noise_rows:
        write_rows(out / "f1_vs_noise.csv", result.noise_rows, NoiseDetectionRow)
        plotting.plot_f1_vs_noise(result.noise_rows, out / "fig_f1_vs_noise.png")


def write_anomalies(result, out, *, command: str, elapsed: float) -> None:
    """Write every output of ``roadcollab anomalies`` to ``out``.

    Files: ``detection.csv``, ``detection_per_vehicle.csv``, ``fig_anomaly_map.png`` with its CSV,
    ``f1_vs_depth`` / ``f1_vs_noise`` (CSV and figure) when swept, ``config.json`` and ``report.md``.

    Parameters
    ----------
    result : roadcollab.experiments.anomalies.study.AnomalyStudyResult
        The anomaly study.
    out : str or Path
        Output folder (created if missing; files overwritten).
    command : str
        The command line, recorded in ``config.json`` and the report.
    elapsed : float
        Wall-clock time of the study, s.
    """
    out = output_dir(out)
    write_rows(out / "detection.csv", result.detection_rows, DetectionRow)
    write_rows(out / "detection_per_vehicle.csv", result.vehicle_rows, VehicleDetectionRow)
    plotting.plot_anomaly_map(result.map_example, out / "fig_anomaly_map.png")
    write_rows(out / "fig_anomaly_map.csv", result.map_example.to_rows(), MapRow)
    _write_curves(result, out)
    write_config(out / "config.json", command=command, seed=result.seed, config=result.config.to_dict(),
                 extra={"elapsed_s": elapsed})
    text = run_header("# roadcollab anomalies: detecting potholes and bumps from the estimates", command, elapsed)
    (out / "report.md").write_text("\n".join(text + [anomaly_markdown(result)]))
