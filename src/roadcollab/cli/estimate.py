"""``roadcollab estimate --drive FILE [--drive FILE ...] --out DIR``: the road from recorded drives.

Reads the drives (:mod:`roadcollab.io.drives`, file formats there), runs Algorithm 1 down them
(:mod:`roadcollab.experiments.drive_estimation`), looks for anomalies and writes CSV files,
figures, ``config.json`` and ``report.md`` (:mod:`roadcollab.reporting.drives_report`).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import asdict

from ..errors import ParameterError
from ..io.limits import FileLimits
from ._common import add_limit_options, command_parser, file_limits, positive_float

__all__ = ["NAME", "add_estimate_arguments", "estimate_command", "add_parser", "run"]

NAME = "estimate"


def _detector_config() -> dict | None:
    """The anomaly detector's default settings for ``config.json``."""
    from ..detection.detector import DetectorSpec

    return asdict(DetectorSpec())


def _time_grid(drives, out, *, command: str, segment_length: float, t0: float) -> dict:
    """The drives share one time grid: relay in time as the simulations do, then IRI of the fused elevation."""
    from ..experiments.drive_estimation import estimate_drives, find_anomalies
    from ..models.iri import iri_segments
    from ..reporting.drives_report import write_estimates

    est = estimate_drives(drives)
    note = None
    try:
        anomalies = find_anomalies(est)
    except ParameterError as err:  # e.g. a window shorter than the longest template
        anomalies, note = None, f"Anomaly detection was not run: {err}."
    try:
        iri, iri_note = iri_segments(est.positions, est.elevation["fused"][-1], segment_length), None
    except ParameterError as err:
        iri, iri_note = None, f"IRI was not computed: {err}."
    return write_estimates(est, out, command=command, anomalies=anomalies, anomaly_note=note,
                           elapsed=time.perf_counter() - t0, detector_config=_detector_config(), iri=iri,
                           iri_note=iri_note)


def _distance_grid(drives, out, *, command: str, segment_length: float, align: bool, max_offset: float,
                   spacing: float, t0: float) -> dict:
    """Drives on different grids (or aligned): every estimate on one distance grid."""
    from ..experiments.fleet_estimation import estimate_fleet, find_fleet_anomalies, fused_iri
    from ..reporting.fleet_report import write_fleet_estimates

    est = estimate_fleet(drives, spacing=spacing, align=align, max_offset=max_offset)
    notes = []
    try:
        anomalies = find_fleet_anomalies(est)
    except ParameterError as err:
        anomalies = []
        notes.append(f"Anomaly detection was not run: {err}.")
    iri, iri_note = fused_iri(est, segment_length)
    if iri_note:
        notes.append(iri_note)
    resampled = [d.csv_path.name for d in drives if d.resampled]
    if resampled:
        notes.append(f"Jittery time stamps were resampled (cubic spline at the mean rate): {', '.join(resampled)}.")
    return write_fleet_estimates(est, out, command=command, anomalies=anomalies, iri=iri, notes=notes,
                                 elapsed=time.perf_counter() - t0)


def estimate_command(drive_paths: list[str], out_dir, *, command: str, limits: FileLimits | None = None,
                     segment_length: float = 100.0, align: bool = False, max_offset: float = 10.0,
                     spacing: float = 0.05) -> dict:
    """Everything ``roadcollab estimate`` does: read, estimate, detect, IRI, write.

    Drives that share one time grid (constant speed, sample rate and start) are relayed in time
    exactly as the simulations are (:func:`~roadcollab.experiments.drive_estimation.estimate_drives`);
    any others, or with ``align``, are estimated on one distance grid
    (:func:`~roadcollab.experiments.fleet_estimation.estimate_fleet`).

    Parameters
    ----------
    drive_paths : list of str
        The drive CSVs in driving order (parameters files beside them).
    out_dir : str or Path
        Output folder (created).
    command : str
        The command line, recorded in ``config.json`` and ``report.md``.
    limits : FileLimits, optional
        Largest drive CSV (MB) and most rows (default ``FileLimits()``).
    segment_length : float
        IRI segment length, m.
    align : bool
        Estimate the drives' start offsets by cross-correlation (distance grid).
    max_offset : float
        Largest offset between two drives searched, m.
    spacing : float
        Step of the distance grid, m.

    Returns
    -------
    dict
        Summary of :func:`~roadcollab.reporting.drives_report.write_estimates` (``grid`` = ``"time"``)
        or :func:`~roadcollab.reporting.fleet_report.write_fleet_estimates` (``"distance"``).

    Raises
    ------
    ParameterError
        An unusable ``out_dir`` (before anything is read) or bad input files
        (:class:`~roadcollab.errors.FileFormatError`); ``out_dir`` is untouched then.
    """
    from ..io.drives import common_time_grid, load_drives
    from ..reporting.records import staged_output

    t0 = time.perf_counter()
    with staged_output(out_dir) as out:
        drives = load_drives(drive_paths, limits=limits)
        if common_time_grid(drives) and not align:
            summary = _time_grid(drives, out, command=command, segment_length=segment_length, t0=t0)
        else:
            summary = _distance_grid(drives, out, command=command, segment_length=segment_length, align=align,
                                     max_offset=max_offset, spacing=spacing, t0=t0)
    return {**summary, "out_dir": str(out_dir)}


def add_estimate_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``roadcollab estimate``: ``--drive FILE`` (repeatable, in driving order) and ``--out DIR``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The parser the options are added to.
    """
    parser.add_argument("--drive", action="append", required=True, metavar="FILE",
                        help="drive CSV 'time_s,accel_left,accel_right[,speed_mps|,distance_m]' (m/s^2) with FILE's "
                             "stem + .toml or .json beside it (speed_mps unless a column gives it, start_m, [vehicle] "
                             "estimated parameters); repeat in driving order")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="output folder (written as a whole at the end; a failed run leaves it untouched)")
    parser.add_argument("--segment-length", type=positive_float, default=100.0, metavar="M",
                        help="IRI segment length of the fused elevation, m (default 100)")
    parser.add_argument("--align", action="store_true",
                        help="estimate each drive's start offset (GPS error) by cross-correlating the drives' "
                             "inversions on distance, apply it and write offsets.csv")
    parser.add_argument("--max-offset", type=positive_float, default=10.0, metavar="M",
                        help="largest start offset between two drives searched with --align, m (default 10)")
    parser.add_argument("--grid-step", type=positive_float, default=0.05, metavar="M",
                        help="step of the distance grid for drives at different speeds, m (default 0.05)")
    add_limit_options(parser, "each drive CSV")


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``estimate`` subcommand and its options.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        From ``ArgumentParser.add_subparsers``.

    Returns
    -------
    argparse.ArgumentParser
        The subcommand's parser.
    """
    p = command_parser(
        subparsers, NAME, summary="estimate the road from recorded drives (CSV + parameters)",
        does="Reads recorded drives (an acceleration CSV per drive with a .toml or .json parameters file beside "
             "it), relays Algorithm 1 down them in the order given, fuses the estimates and looks for anomalies. "
             "A bad file is refused with one line naming the file, the line and the field.",
        writes="into --out (replaced as a whole at the end): road_estimates.csv, final_estimate.csv, "
               "anomalies.csv, iri.csv, offsets.csv (drives at different speeds/starts), figures, config.json, "
               "report.md.",
        example="roadcollab estimate --drive d1.csv --drive d2.csv --out results/road")
    add_estimate_arguments(p)
    return p


def run(args: argparse.Namespace, command_line: str) -> int:
    """Estimate the road from ``args.drive``, write the outputs to ``args.out`` and print the notes.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options of :func:`add_parser`.
    command_line : str
        The command line, recorded in ``config.json`` and ``report.md``.

    Returns
    -------
    int
        Exit status 0.
    """
    summary = estimate_command(args.drive, args.out, command=command_line, limits=file_limits(args),
                               segment_length=args.segment_length, align=args.align, max_offset=args.max_offset,
                               spacing=args.grid_step)
    for note in summary.get("notes", []):
        print(f"note: {note}")
    print(f"estimated {summary['n_drives']} drives over {summary['length_m']:.1f} m ({summary['grid']} grid); "
          f"wrote {args.out}/report.md")
    return 0
