"""Outputs of ``roadcollab estimate`` for drives on different grids (speeds, rates, starts): on distance.

Files: ``road_estimates.csv`` (``position_m`` and ``elevation_<estimator>_v<k>_<side>`` for every
drive ``k`` and estimator single/inversion/collaborative/fused, blank where drive ``k`` did not pass),
``final_estimate.csv`` (one schema with the time grid, :mod:`roadcollab.reporting.drive_tables`),
``offsets.csv``, ``iri.csv``, ``anomalies.csv``, ``elevation.png``,
``config.json`` and ``report.md``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..experiments.drives.estimation import AnomalyRow, OffsetRow
from ..experiments.drives.fleet_estimation import FLEET_ESTIMATORS, FleetEstimates, covered_runs
from ..models.iri import IRIRow, IRISegments
from . import plotting_drives
from .drive_tables import write_array_csv, write_final_estimate
from .records import markdown_table, row_columns, write_config, write_rows

__all__ = ["FLEET_FILES", "iri_lines", "write_iri_csv", "write_fleet_estimates"]

FLEET_FILES = ["road_estimates.csv", "final_estimate.csv", "offsets.csv", "iri.csv", "anomalies.csv",
               "elevation.png", "config.json", "report.md"]
_SIDES = ("left", "right")
_IRI_COLUMNS = row_columns(IRIRow)


def _blank(v: float):
    """A CSV cell: the float, or an empty string for NaN (a drive that did not pass)."""
    return "" if not np.isfinite(v) else float(v)


def write_iri_csv(path, iri: IRISegments | None) -> None:
    """``iri.csv`` (``start_m, end_m, iri_left_m_per_km, iri_right_m_per_km, iri_m_per_km``; header only if None).

    Parameters
    ----------
    path : str or Path
    iri : IRISegments or None
    """
    write_rows(path, iri.to_rows() if iri is not None else [], IRIRow)


def iri_lines(iri: IRISegments | None, note: str | None, band_note: str) -> list[str]:
    """The report section ``IRI of the fused elevation``.

    Parameters
    ----------
    iri : IRISegments or None
    note : str or None
        Why it was not computed.
    band_note : str
        What the elevation's band limit does to the IRI.

    Returns
    -------
    list of str
    """
    lines = ["## IRI of the fused elevation (`iri.csv`)", ""]
    if iri is None:
        return lines + [note or "IRI was not computed.", ""]
    return lines + [f"Golden Car at 80 km/h (ASTM E1926) per {float(iri.end[0] - iri.start[0]):g} m segment of the "
                    f"fused elevation; mean {float(np.mean(iri.mean)):.3f} m/km. {band_note}", "",
                    markdown_table(iri.to_rows(), _IRI_COLUMNS,
                                   ["start (m)", "end (m)", "left (m/km)", "right (m/km)", "mean (m/km)"]), ""]


def _tables(est: FleetEstimates, out: Path, anomalies: list[AnomalyRow]) -> None:
    V = len(est.drives)
    named = [(f"elevation_{name}_v{j + 1}_{side}", est.elevation[name][j][:, c])
             for j in range(V) for name in FLEET_ESTIMATORS for c, side in enumerate(_SIDES)]
    write_array_csv(out / "road_estimates.csv", ["position_m"] + [n for n, _ in named],    # blank: did not pass
                    [est.position] + [series for _, series in named])
    write_final_estimate(out / "final_estimate.csv", est.position, est.fused, est.elevation["collaborative"][-1],
                         est.coverage)
    rows = [OffsetRow(j + 1, d.csv_path.name, d.start_m, float(est.offsets[j]), d.start_m + float(est.offsets[j]),
                      _blank(est.offset_peaks[j])) for j, d in enumerate(est.drives)]
    write_rows(out / "offsets.csv", rows, OffsetRow)
    write_rows(out / "anomalies.csv", anomalies, AnomalyRow)


def _figure(est: FleetEstimates, out: Path) -> None:
    series = {f"inversion, drive {j + 1}": e for j, e in enumerate(est.elevation["inversion"])}
    series = dict(list(series.items())[-2:])
    series[f"fused (drives 1-{len(est.drives)})"] = est.fused
    plotting_drives.plot_tracks(est.position, series, out / "elevation.png", ylabel="elevation (m)",
                                title=f"Elevation on distance (wavelengths below {1 / est.band_low_per_m:.3g} m)")


def _drive_rows(est: FleetEstimates) -> list[dict]:
    rows = []
    for j, d in enumerate(est.drives):
        v = d.speeds()
        rows.append({"drive": j + 1, "csv": d.csv_path.name, "rate (Hz)": d.sample_rate,
                     "speed (m/s)": f"{v.min():.3g}-{v.max():.3g}" if not d.constant_speed else f"{d.speed:g}",
                     "speed from": d.speed_source, "start (m)": d.start_m, "end (m)": round(float(d.positions[-1]), 3),
                     "resampled": "yes" if d.resampled else "no", "offset (m)": round(float(est.offsets[j]), 3)})
    return rows


def _method_lines(est: FleetEstimates) -> list[str]:
    return [
        "## What was computed",
        "",
        "The drives do not share one time grid (speeds, sample rates or starts differ, or the speed varies), so "
        "every estimate lives on one uniform distance grid "
        f"(step {est.spacing:g} m). Each vehicle inverts its own record in its own time base (its suspension is "
        "time-invariant in time, not in distance), designed at its mean speed; the road velocity is integrated to "
        "the elevation at the sample instants and mapped to road distance by a cubic spline through the sample "
        "positions (constant speed, logged speed or logged distance).",
        "",
        f"- Every elevation is band-limited in wavenumber from {est.band_low_per_m:.4g} cycles/m (wavelengths above "
        f"about {1 / est.band_low_per_m:.3g} m are not estimated): {est.band_low_hz:g} Hz at the lowest speed of any "
        "drive. Each drive's stretch is band-limited separately; its first and last tens of metres carry "
        "window-edge effects.",
        "- **single**: the vehicle's own observer; **inversion**: its own offline inversion; **collaborative**: "
        "Algorithm 1 with the previous drive's inversion mapped through distance into this vehicle's time; "
        "**fused** (drive k): the average of the inversions of drives 1..k that passed each point.",
        "- Blank cells: the drive did not pass that point.",
        "",
    ]


def write_fleet_estimates(est: FleetEstimates, out, *, command: str, anomalies: list[AnomalyRow],
                          iri: IRISegments | None, notes: list[str], elapsed: float | None = None,
                          cleaning: list[dict] | None = None) -> dict:
    """Write every output of ``roadcollab estimate`` on distance (module docstring); returns the summary.

    Parameters
    ----------
    est : FleetEstimates
    out : str or Path
        Output folder (created if missing).
    command : str
        The command line.
    anomalies : list of AnomalyRow
        Detections in the fused elevation.
    iri : IRISegments or None
        IRI of the fused elevation (None: see ``notes``).
    notes : list of str
        Caveats for the report and ``config.json``.
    elapsed : float, optional
        Wall time, s.
    cleaning : list of dict, optional
        Per drive, what :func:`roadcollab.io.drive_clean.clean_drive` did (``config.json``).

    Returns
    -------
    dict
        ``out_dir``, ``n_drives``, ``grid``, ``length_m``, ``offsets_m``, ``n_anomalies``, ``notes``, ``files``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    _tables(est, out, anomalies)
    write_iri_csv(out / "iri.csv", iri)
    _figure(est, out)
    # Road covered by any drive, m (separate stretches are summed, not bridged).
    length = float(sum(est.position[r][-1] - est.position[r][0] for r in covered_runs(
        np.where(est.coverage[:, None] > 0, 0.0, np.nan))))
    config = {"drives": [d.describe() for d in est.drives], "grid": "distance", "spacing_m": est.spacing,
              "band_low_per_m": est.band_low_per_m, "band_low_hz": est.band_low_hz, "gamma": est.gamma,
              "aligned": est.aligned, "offsets_m": est.offsets.tolist(), "cleaning": cleaning,
              "receiver_guard": est.receiver_guard}
    write_config(out / "config.json", command=command, seed=None, config=config,
                 extra={"notes": notes, **({"elapsed_s": elapsed} if elapsed is not None else {})})
    band_note = (f"The elevation holds wavelengths below about {1 / est.band_low_per_m:.3g} m only; the Golden Car "
                 "also responds to longer ones, so this IRI is a lower estimate.")
    lines = ["# roadcollab estimate: the road on distance from drives at different speeds", "",
             f"Command: `{command}`  ", f"{len(est.drives)} drive(s) over {length:.1f} m of road"
             + (f"; {elapsed:.1f} s." if elapsed is not None else "."), ""]
    if notes:
        lines += ["**Notes.**", ""] + [f"- {n}" for n in notes] + [""]
    drive_rows = _drive_rows(est)
    lines += ["## Inputs", "", markdown_table(drive_rows, list(drive_rows[0])), "",
              "Offsets (`offsets.csv`): " + ("estimated by cross-correlating each drive's band-limited inversion "
                                             "with the fusion of the drives before it, shifted to mean zero." if
                                             est.aligned else "none applied (use --align to estimate them)."), ""]
    lines += _method_lines(est) + ["## Elevation", "", "![elevation](elevation.png)", ""]
    lines += iri_lines(iri, next((n for n in notes if n.startswith("IRI")), None), band_note)
    lines += ["## Anomalies in the fused elevation (`anomalies.csv`)", "",
              markdown_table(anomalies, ["position_m", "side", "kind", "depth_m", "confidence"])
              if anomalies else "None.", ""]
    (out / "report.md").write_text("\n".join(lines))
    return {"out_dir": str(out), "n_drives": len(est.drives), "grid": "distance", "length_m": length,
            "offsets_m": est.offsets.tolist(), "n_anomalies": {"fused": len(anomalies)}, "notes": notes,
            "files": list(FLEET_FILES)}
