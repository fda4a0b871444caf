"""Report of ``roadcollab iri``: ``iri.csv``, ``iri.png``, ``config.json``, ``report.md``."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..models.iri import GoldenCar, IRIRow, IRISegments
from . import plotting_iri
from .records import markdown_table, output_dir, row_columns, run_header, write_config, write_rows

__all__ = ["iri_markdown", "write_iri"]

_COLUMNS = row_columns(IRIRow)


def iri_markdown(result: IRISegments, *, source: str, car: GoldenCar) -> str:
    """The body of the IRI report: method, summary and the per-segment table.

    Parameters
    ----------
    result : IRISegments
    source : str
        Name of the profile file.
    car : GoldenCar
        The car, speed and processing used.

    Returns
    -------
    str
        Markdown, ending in a newline.
    """
    seg = float(result.end[0] - result.start[0])
    tracks = ("one measured track (left and right columns are that track)" if result.tracks == 1
              else "two tracks (left, right)")
    mean = result.mean
    lines = [
        f"Profile `{source}`, {tracks}; {len(result.start)} whole segments of {seg:g} m from "
        f"{result.start[0]:g} m.",
        "",
        f"Golden Car (Sayers, Gillespie and Queiroz 1986; ASTM E1926): k1 = {car.tyre_stiffness:g}, "
        f"k2 = {car.suspension_stiffness:g} 1/s^2, c = {car.suspension_damping:g} 1/s, mu = {car.mass_ratio:g}, "
        f"at {3.6 * car.speed:g} km/h; {1000 * car.smoothing_length:g} mm moving average of the profile; "
        f"initial slope over the first {car.initial_length:g} m; exact state transition per sample step "
        "(Sayers 1995). IRI = mean |suspension rate| / speed, m/km.",
        "",
        f"Mean IRI {float(np.mean(mean)):.3f} m/km; segments from {float(mean.min()):.3f} to "
        f"{float(mean.max()):.3f} m/km.",
        "",
        "![IRI per segment](iri.png)",
        "",
        "## IRI per segment (`iri.csv`)",
        "",
        markdown_table(result.to_rows(), _COLUMNS,
                       ["start (m)", "end (m)", "left (m/km)", "right (m/km)", "mean (m/km)"]),
    ]
    return "\n".join(lines) + "\n"


def write_iri(result: IRISegments, out, *, command: str, source: str, car: GoldenCar, elapsed: float) -> Path:
    """Write ``iri.csv``, ``iri.png``, ``config.json`` and ``report.md`` to ``out``.

    Parameters
    ----------
    result : IRISegments
    out : str or Path
        Output folder (created if missing).
    command : str
        The command line of the run (recorded in config.json and the report).
    source : str
        The profile file as given (``packaged`` name for the shipped one).
    car : GoldenCar
        The car, speed and processing used.
    elapsed : float
        Wall-clock time of the computation, s.

    Returns
    -------
    Path
        ``out``.
    """
    out = output_dir(out)
    write_rows(out / "iri.csv", result.to_rows(), IRIRow)
    series = {"mean of the tracks" if result.tracks == 2 else "IRI of the measured track": result.mean}
    if result.tracks == 2:
        series.update({"left track": result.left, "right track": result.right})
    plotting_iri.plot_iri(result.start, result.end, series, out / "iri.png",
                          title=f"IRI per {float(result.end[0] - result.start[0]):g} m segment, {Path(source).name}")
    seg = float(result.end[0] - result.start[0])
    write_config(out / "config.json", command=command, seed=None,
                 config={"road_profile": source, "segment_length_m": seg, "golden_car": asdict(car)},
                 extra={"tracks": result.tracks, "elapsed_s": elapsed})
    (out / "report.md").write_text("\n".join(
        run_header("# roadcollab iri: International Roughness Index per segment", command, elapsed)
        + [iri_markdown(result, source=source, car=car)]))
    return out
