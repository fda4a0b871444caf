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
from ..detection.detector import DetectorSpec
from ..experiments.drive_estimation import estimate_drives, find_anomalies
from ..io.drives import load_drives
from ..io.limits import FileLimits
from ..reporting.drives_report import write_estimates
from ..reporting.records import staged_output
from ._common import add_limit_options, command_parser, file_limits

__all__ = ["NAME", "add_estimate_arguments", "estimate_command", "add_parser", "run"]

NAME = "estimate"


def _detector_config() -> dict | None:
    """The anomaly detector's default settings for ``config.json``."""
    return asdict(DetectorSpec())


def estimate_command(drive_paths: list[str], out_dir, *, command: str, limits: FileLimits | None = None) -> dict:
    """Everything ``roadcollab estimate`` does: read, estimate, detect, write.

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

    Returns
    -------
    dict
        Summary: ``out_dir``, ``n_drives``, ``sample_rate_hz``, ``speed_mps``, ``start_m``,
        ``n_samples``, ``samples_per_drive``, ``truncated``, ``duration_s``, ``length_m``,
        ``n_anomalies`` (per estimator, summed over drives; None if detection was not run),
        ``notes`` and ``files``.

    Raises
    ------
    ParameterError
        An unusable ``out_dir`` (before anything is read) or bad input files
        (:class:`~roadcollab.errors.FileFormatError`); ``out_dir`` is untouched then.
    """
    t0 = time.perf_counter()
    with staged_output(out_dir) as out:
        drives = load_drives(drive_paths, limits=limits)
        est = estimate_drives(drives)
        note = None
        try:
            anomalies = find_anomalies(est)
        except ParameterError as err:  # e.g. a window shorter than the longest template
            anomalies, note = None, f"Anomaly detection was not run: {err}."
        summary = write_estimates(est, out, command=command, anomalies=anomalies, anomaly_note=note,
                                  elapsed=time.perf_counter() - t0, detector_config=_detector_config())
    return {**summary, "out_dir": str(out_dir)}


def add_estimate_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``roadcollab estimate``: ``--drive FILE`` (repeatable, in driving order) and ``--out DIR``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The parser the options are added to.
    """
    parser.add_argument("--drive", action="append", required=True, metavar="FILE",
                        help="drive CSV 'time_s,accel_left,accel_right' (m/s^2) with FILE's stem + .toml or .json "
                             "beside it (speed_mps, [vehicle] estimated parameters); repeat in driving order")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="output folder (written as a whole at the end; a failed run leaves it untouched)")
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
               "anomalies.csv, figures, config.json, report.md.",
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
    summary = estimate_command(args.drive, args.out, command=command_line, limits=file_limits(args))
    for note in summary.get("notes", []):
        print(f"note: {note}")
    print(f"estimated {summary['n_drives']} drives over {summary['length_m']:.1f} m; wrote {args.out}/report.md")
    return 0
