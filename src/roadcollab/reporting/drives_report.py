"""Outputs of ``roadcollab estimate``: CSV tables, figures, ``config.json`` and ``report.md``.

One function per output file or report section; :func:`write_estimates` writes them all.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..experiments.drives.estimation import ESTIMATORS, AnomalyRow, DriveEstimates
from ..experiments.config import ExperimentConfig
from . import plotting_drives
from ..models.iri import IRISegments
from .fleet_report import iri_lines, write_iri_csv
from .drive_tables import write_array_csv, write_final_estimate
from .records import markdown_table, row_columns, write_config, write_rows

__all__ = ["ESTIMATE_FILES", "write_estimates"]

ESTIMATE_FILES = ["road_estimates.csv", "final_estimate.csv", "anomalies.csv", "iri.csv", "road_velocity.png",
                  "elevation.png", "config.json", "report.md"]
_SIDES = ("left", "right")


def _duration_s(est: DriveEstimates) -> float:
    """Length of the common window, s."""
    return est.n_samples / est.sample_rate


def _length_m(est: DriveEstimates) -> float:
    """Length of road covered by the common window, m."""
    return est.speed * est.n_samples / est.sample_rate


# --- CSV tables ----------------------------------------------------------------------------------

def _estimate_series(est: DriveEstimates) -> list[tuple[str, np.ndarray]]:
    """``w_<estimator>_v<k>_<side>`` (m/s), then ``elevation_<estimator>_v<k>_<side>`` (m), every drive k."""
    named = []
    for kind, data in (("w", est.velocity), ("elevation", est.elevation)):
        for j in range(len(est.drives)):
            for name in ESTIMATORS:
                for c, side in enumerate(_SIDES):
                    named.append((f"{kind}_{name}_v{j + 1}_{side}", data[name][j, :, c]))
    return named


def _write_tables(est: DriveEstimates, out: Path, anomaly_rows: list[AnomalyRow]) -> None:
    """``road_estimates.csv``, ``final_estimate.csv`` (:data:`~roadcollab.reporting.drive_tables.FINAL_COLUMNS`)
    and ``anomalies.csv`` in ``out``."""
    named = _estimate_series(est)
    write_array_csv(out / "road_estimates.csv", ["position_m", "time_s"] + [n for n, _ in named],
                    [est.positions, est.time] + [series for _, series in named])
    write_final_estimate(out / "final_estimate.csv", est.positions, est.elevation["fused"][-1],
                         est.elevation["collaborative"][-1], np.full(est.n_samples, len(est.drives)))
    write_rows(out / "anomalies.csv", anomaly_rows, AnomalyRow)


# --- figures -------------------------------------------------------------------------------------

def _zoom_window(est: DriveEstimates, width_m: float = 20.0) -> tuple[float, float] | None:
    """A ``width_m`` stretch around the largest fused road velocity of the last drive (away from the
    window edges), for the figures' zoom column; None if the window is not much longer."""
    pos = est.positions
    length = pos[-1] - pos[0]
    if length < 3 * width_m:
        return None
    w = np.max(np.abs(est.velocity["fused"][-1]), axis=1)
    inner = (pos >= pos[0] + width_m) & (pos <= pos[-1] - width_m)
    center = float(pos[inner][np.argmax(w[inner])])
    return center - width_m / 2, center + width_m / 2


def _write_figures(est: DriveEstimates, out: Path) -> tuple[float, float] | None:
    """``road_velocity.png`` and ``elevation.png`` of the last drive; returns the zoom window (m) or None."""
    V = len(est.drives)
    last = {name: est.velocity[name][-1] for name in ESTIMATORS}
    labels = {"single": f"single vehicle (drive {V})", "collaborative": f"collaborative, Algorithm 1 (drive {V})",
              "fused": f"fused (average of drives 1-{V})"}
    zoom = _zoom_window(est)
    plotting_drives.plot_tracks(est.positions, {labels[k]: v for k, v in last.items()}, out / "road_velocity.png",
                                ylabel="road velocity (m/s)", zoom=zoom,
                                title=f"Band-limited road-velocity estimates (from {est.band_low_hz:g} Hz)")
    plotting_drives.plot_tracks(est.positions, {labels[k]: est.elevation[k][-1] for k in ESTIMATORS},
                                out / "elevation.png", ylabel="elevation (m)", zoom=zoom,
                                title=f"Elevation estimates (mean removed; wavelengths above "
                                      f"{est.speed / est.band_low_hz:g} m not observed)")
    return zoom


# --- config.json ---------------------------------------------------------------------------------

def _notes(est: DriveEstimates, anomaly_note: str | None) -> list[str]:
    """Caveats for the report and ``config.json``: truncation, a window too short, the anomaly note."""
    notes = []
    if est.n_windows > 1:
        notes.append(f"The {est.n_samples} samples were estimated in {est.n_windows} overlapping windows (memory "
                     "stays bounded; measured within 3e-11 of one window on a 10-minute drive).")
    if est.truncated:
        lengths = [d.n_samples for d in est.drives]
        notes.append(f"Drives have {', '.join(map(str, lengths))} samples; all were truncated to the shortest, "
                     f"{est.n_samples} samples ({est.n_samples / est.sample_rate:.6g} s).")
    duration = _duration_s(est)
    if duration < 4.0 / est.band_low_hz:
        notes.append(f"The common window ({duration:.6g} s) is shorter than two periods of the {est.band_low_hz:g} Hz "
                     "band edge: the estimates are dominated by window-edge effects; log longer drives.")
    if anomaly_note:
        notes.append(anomaly_note)
    return notes


def _write_config_json(est: DriveEstimates, path: Path, *, command: str, notes: list[str], elapsed: float | None,
                       detector_config: dict | None, cleaning: list[dict] | None) -> None:
    """``config.json``: the drives, the common grid, the estimator design and the detector settings."""
    design = ExperimentConfig()
    config = {
        "drives": [d.describe() for d in est.drives],
        "sample_rate_hz": est.sample_rate, "speed_mps": est.speed, "start_m": est.start_m,
        "n_samples_used": est.n_samples, "truncated": est.truncated,
        "gamma": est.gamma, "band_low_hz": est.band_low_hz,
        "estimator_design": {"iso_class": design.iso_class, "anomaly_density": design.anomaly_density,
                             "note": "noise model of ExperimentConfig(speed, sample_rate, sensor_noise_std)"},
        "anomaly_detector": detector_config,
        "n_windows": est.n_windows,
        "receiver_guard": est.receiver_guard,
        "cleaning": cleaning,
    }
    extra: dict[str, object] = {"notes": notes}
    if elapsed is not None:
        extra["elapsed_s"] = elapsed
    write_config(path, command=command, seed=None, config=config, extra=extra)


# --- report.md -----------------------------------------------------------------------------------

def _report_header(est: DriveEstimates, *, command: str, notes: list[str], elapsed: float | None) -> list[str]:
    """Title, command, the common window and the notes."""
    V = len(est.drives)
    lines = [
        "# roadcollab estimate: road input, elevation and anomalies from recorded drives",
        "",
        f"Command: `{command}`  ",
        f"{V} drive(s) in this order; {est.sample_rate:.9g} Hz; {est.speed:g} m/s; {est.n_samples} samples "
        f"({est.n_samples / est.sample_rate:.6g} s, road {est.start_m:g} to {est.start_m + _length_m(est):.6g} m)"
        + (f"; read, estimated and searched in {elapsed:.1f} s." if elapsed is not None else "."),
        "",
    ]
    if notes:
        lines += ["**Notes.**", ""] + [f"- {n}" for n in notes] + [""]
    return lines


def _inputs_section(est: DriveEstimates) -> list[str]:
    """Every drive's files, sample count, sensor noise and estimated vehicle parameters."""
    drive_rows = [{"drive": j + 1, "csv": d.csv_path.name, "params": d.params_path.name, "samples": d.n_samples,
                   "noise": d.sensor_noise_std, "m_b": d.params.sprung_mass, "I_x": d.params.roll_inertia,
                   "L1": d.params.left_arm, "L2": d.params.right_arm, "k_s": d.params.stiffness,
                   "c_s": d.params.damping} for j, d in enumerate(est.drives)]
    return [
        "## Inputs",
        "",
        "Estimated vehicle parameters (SI units: kg, kg m^2, m, N/m, N s/m) and sensor noise (m/s^2):",
        "",
        markdown_table(drive_rows, list(drive_rows[0])),
        "",
    ]


def _method_section(est: DriveEstimates) -> list[str]:
    """What the estimators are, the band limit, the elevation's drift and the CSV columns."""
    return [
        "## What was computed",
        "",
        f"- Per drive k: **single** = the vehicle's own road-input observer (gamma {est.gamma:g}); **collaborative** "
        "= Algorithm 1 with the message of drive k-1 (drive 1: observer only, equal to single); **fused** = the "
        "running average of the band-limited model inversions of drives 1..k.",
        "- The estimators are designed (Lemma 1) for an ISO 8608 class C road with the default pothole statistics "
        "at this speed and each drive's sensor noise; only the *estimated* vehicle parameters are used.",
        f"- All road velocities are band-limited from {est.band_low_hz:g} Hz (W(f) = 1 / (1 + ({est.band_low_hz:g} Hz "
        "/ f)^8)): accelerometers cannot see a constant road velocity (DC), so it is not estimated.",
        f"- Elevation = the integral of the band-limited road velocity, mean removed. It is defined only up to a "
        f"slow drift: wavelengths above {est.speed / est.band_low_hz:g} m (speed / {est.band_low_hz:g} Hz) are not "
        "observed.",
        "- The first and last second or so of every estimate carry window-edge effects of the offline filters.",
        "- `road_estimates.csv`: `position_m`, `time_s` (since each drive's first sample), then "
        "`w_<estimator>_v<k>_<left|right>` (m/s) and `elevation_<estimator>_v<k>_<left|right>` (m) for every "
        "drive k and estimator single/collaborative/fused. `final_estimate.csv`: `position_m`, "
        "`elevation_fused_left|right` (all drives), `coverage` (drives), `elevation_collaborative_left|right` "
        "(the last drive), the same columns whichever grid ran. `anomalies.csv`: every detection of every "
        "estimator and drive.",
        "",
    ]


def _figures_section(est: DriveEstimates, zoom: tuple[float, float] | None) -> list[str]:
    """The road-velocity and elevation figures of the last drive."""
    V = len(est.drives)
    return [
        f"## Road velocity, drive {V}",
        "",
        "Single vehicle, collaborative and fused estimates of the last drive"
        + (f"; right: a zoom on {zoom[0]:.1f}-{zoom[1]:.1f} m, around the largest fused road velocity." if zoom
           else "."),
        "",
        "![road velocity](road_velocity.png)",
        "",
        f"## Elevation, drive {V}",
        "",
        "![elevation](elevation.png)",
        "",
    ]


def _anomaly_counts(est: DriveEstimates, anomaly_rows: list[AnomalyRow]) -> dict[str, list[int]]:
    """``{estimator: [detections in drive 1, drive 2, ...]}``."""
    V = len(est.drives)
    return {name: [sum(1 for r in anomaly_rows if r.estimator == name and r.vehicle == j + 1)
                   for j in range(V)] for name in ESTIMATORS}


def _anomalies_section(est: DriveEstimates, anomalies: list[AnomalyRow] | None, counts: dict[str, list[int]]
                       ) -> list[str]:
    """Detections per drive and estimator, and the last drive's collaborative and fused detections."""
    V = len(est.drives)
    lines = ["## Anomalies (`anomalies.csv`)", ""]
    if anomalies is None:
        return lines + ["Anomaly detection was not run.", ""]
    count_rows = [{"drive": j + 1, **{name: counts[name][j] for name in ESTIMATORS}} for j in range(V)]
    final = [r for r in anomalies if r.vehicle == V and r.estimator in ("collaborative", "fused")]
    lines += ["Detections per drive and estimator:", "", markdown_table(count_rows, ["drive", *ESTIMATORS]), "",
              f"Detections in drive {V}'s collaborative and fused estimates (position = center):", ""]
    return lines + [markdown_table(final, row_columns(AnomalyRow)) if final else "None.", ""]


# --- everything ----------------------------------------------------------------------------------

def write_estimates(est: DriveEstimates, out, *, command: str, anomalies: list[AnomalyRow] | None,
                    anomaly_note: str | None = None, elapsed: float | None = None,
                    detector_config: dict | None = None, iri: IRISegments | None = None,
                    iri_note: str | None = None, cleaning: list[dict] | None = None,
                    extra_notes: list[str] | None = None) -> dict:
    """Write every output of ``roadcollab estimate`` to the folder ``out``; returns the summary.

    Files: ``road_estimates.csv`` (wide: ``position_m, time_s``, then
    ``w_<estimator>_v<k>_<side>`` in m/s and ``elevation_<estimator>_v<k>_<side>`` in m for every
    drive ``k`` (1-based, driving order), estimator single/collaborative/fused and side left/right),
    ``final_estimate.csv`` (:mod:`roadcollab.reporting.drive_tables`: the fused and the last
    drive's collaborative elevation, one schema for both grids), ``anomalies.csv``,
    ``road_velocity.png``, ``elevation.png``, ``config.json`` and ``report.md``.

    Parameters
    ----------
    est : DriveEstimates
        From :func:`~roadcollab.experiments.drives.estimation.estimate_drives`.
    out : str or Path
        Output folder (created with its parents if missing; files in it are overwritten).
    command : str
        The command line, recorded in ``config.json`` and ``report.md``.
    anomalies : list of AnomalyRow or None
        Rows of :func:`~roadcollab.experiments.drives.estimation.find_anomalies`;
        None if detection was not run (``anomalies.csv`` then holds the header only and the report says so).
    anomaly_note : str, optional
        Note for the report and ``config.json`` (e.g. why detection was not run).
    elapsed : float, optional
        Wall time of reading, estimating and detecting, s (recorded if given).
    detector_config : dict, optional
        Settings of the anomaly detector, recorded in ``config.json`` as ``anomaly_detector``
        (null if None).
    iri : IRISegments, optional
        IRI per segment of the last drive's fused elevation (``iri.csv``; header only if None).
    iri_note : str, optional
        Why the IRI was not computed (a note in the report and ``config.json``).
    cleaning : list of dict, optional
        Per drive, what :func:`roadcollab.io.drive_clean.clean_drive` did (``config.json``).
    extra_notes : list of str, optional
        More notes, first in the report (e.g. the spikes repaired).

    Returns
    -------
    dict
        Summary: ``out_dir``, ``n_drives``, ``sample_rate_hz`` (Hz), ``speed_mps`` (m/s), ``start_m``
        (m), ``n_samples``, ``samples_per_drive``, ``truncated``, ``duration_s`` (s), ``length_m`` (m),
        ``n_anomalies`` (``{estimator: count}`` summed over drives; None if ``anomalies`` is None),
        ``notes`` and ``files``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    anomaly_rows = anomalies or []
    _write_tables(est, out, anomaly_rows)
    write_iri_csv(out / "iri.csv", iri)
    zoom = _write_figures(est, out)
    counts = _anomaly_counts(est, anomaly_rows)
    notes = list(extra_notes or []) + _notes(est, anomaly_note) + ([iri_note] if iri_note else [])
    _write_config_json(est, out / "config.json", command=command, notes=notes, elapsed=elapsed,
                       detector_config=detector_config, cleaning=cleaning)
    lines = (_report_header(est, command=command, notes=notes, elapsed=elapsed) + _inputs_section(est)
             + _method_section(est) + _figures_section(est, zoom) + _anomalies_section(est, anomalies, counts)
             + iri_lines(iri, iri_note, f"The elevation holds wavelengths below {est.speed / est.band_low_hz:g} m "
                                        "only; the Golden Car also responds to longer ones, so this IRI is a lower "
                                        "estimate."))
    (out / "report.md").write_text("\n".join(lines))
    return {
        "out_dir": str(out), "n_drives": len(est.drives), "sample_rate_hz": est.sample_rate, "speed_mps": est.speed,
        "start_m": est.start_m, "n_samples": est.n_samples, "samples_per_drive": [d.n_samples for d in est.drives],
        "truncated": est.truncated, "duration_s": _duration_s(est), "length_m": _length_m(est),
        "n_anomalies": {name: sum(counts[name]) for name in ESTIMATORS} if anomalies is not None else None,
        "notes": notes, "grid": "time",
        "files": list(ESTIMATE_FILES),
    }
