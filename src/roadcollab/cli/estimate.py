"""``roadcollab estimate --drive FILE [--drive FILE ...] --out DIR``: the road from recorded drives.

Reads the drives (:mod:`roadcollab.io.drives`, file formats there), runs Algorithm 1 down them
(:mod:`roadcollab.experiments.drives.estimation`), looks for anomalies and writes CSV files,
figures, ``config.json`` and ``report.md`` (:mod:`roadcollab.reporting.drives_report`).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import asdict

from typing import TYPE_CHECKING

from ..errors import ParameterError
from ._arguments import add_check, help_range
from ._common import (out_path, GRID_STEP, MAX_OFFSET, SEGMENT_LENGTH, add_limit_options, check_file_options,
                      check_segment_length, command_parser, file_limits, plural)

if TYPE_CHECKING:
    from ..io.limits import FileLimits

__all__ = ["NAME", "add_estimate_arguments", "estimate_command", "add_parser", "run"]

NAME = "estimate"


def _detector_config() -> dict | None:
    """The anomaly detector's default settings for ``config.json``."""
    from ..detection.detector import DetectorSpec

    return asdict(DetectorSpec())


def _time_grid(drives, out, *, command: str, segment_length: float, t0: float, cleaning: list[dict],
               notes: list[str], guard: str | None) -> dict:
    """The drives share one time grid: relay in time as the simulations do, then IRI of the fused elevation."""
    from ..experiments.drives.estimation import estimate_drives, find_anomalies
    from ..models.iri import iri_segments
    from ..reporting.drives_report import write_estimates

    est = estimate_drives(drives, guard=guard)
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
                           iri_note=iri_note, cleaning=cleaning, extra_notes=notes)


def _stretches_note(stretches) -> str:
    """Which drives cover which separate stretch of road."""
    parts = [f"drive{'s' if len(g) > 1 else ''} {', '.join(map(str, g))} on {lo:.1f}-{hi:.1f} m"
             for g, lo, hi in stretches]
    return f"{len(stretches)} separate stretches of road: {'; '.join(parts)}"


def _distance_grid(drives, out, *, command: str, segment_length: float, align: bool, max_offset: float,
                   spacing: float, t0: float, notes: list[str], cleaning: list[dict], guard: str | None) -> dict:
    """Drives on different grids (or aligned): every estimate on one distance grid."""
    from ..experiments.drives.fleet_estimation import drive_stretches, estimate_fleet, find_fleet_anomalies, fused_iri
    from ..reporting.fleet_report import write_fleet_estimates

    if align:
        est = estimate_fleet(drives, spacing=spacing, align=align, max_offset=max_offset, guard=guard)
    else:  # the networked run's per-segment engine, over the in-memory transport (equal to estimate_fleet)
        from ..network.memory import estimate_fleet_in_memory

        est = estimate_fleet_in_memory(drives, spacing=spacing, guard=guard)
    notes = list(notes)
    stretches = drive_stretches(drives, segment_length, est.offsets)
    if len(stretches) > 1:
        notes.append(f"The drives do not all overlap by a segment ({segment_length:g} m): "
                     f"{_stretches_note(stretches)}. Each stretch is estimated from its own drives only; nothing is "
                     "fused across the gaps.")
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
    summary = write_fleet_estimates(est, out, command=command, anomalies=anomalies, iri=iri, notes=notes,
                                    elapsed=time.perf_counter() - t0, cleaning=cleaning)
    return {**summary, "stretches": [{"drives": g, "start_m": lo, "end_m": hi} for g, lo, hi in stretches]}


def estimate_command(drive_paths: list[str], out_dir, *, command: str, limits: FileLimits | None = None,
                     segment_length: float = 100.0, align: bool = False, max_offset: float = 10.0,
                     spacing: float = 0.05, guard: str | None = "class") -> dict:
    """Everything ``roadcollab estimate`` does: read, estimate, detect, IRI, write.

    Every drive is cleaned first (:func:`roadcollab.io.drive_clean.clean_drive`: isolated spikes
    repaired and counted, the slow offset such as gravity removed). Drives that share one time grid
    (constant speed, sample rate and start) are relayed in time exactly as the simulations are (:func:`~roadcollab.experiments.drives.estimation.estimate_drives`);
    any others, or with ``align``, are estimated on one distance grid
    (:func:`~roadcollab.experiments.drives.fleet_estimation.estimate_fleet`).

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
    guard : {"class", "own"} or None
        Road prior of every vehicle's receiver guard (:mod:`roadcollab.collaboration.drive_guard`): every
        received message goes through it; None: unguarded, the paper's Algorithm 1 (``--unguarded-receive``).
        Recorded in ``config.json`` as ``receiver_guard``.

    Returns
    -------
    dict
        Summary of :func:`~roadcollab.reporting.drives_report.write_estimates` (``grid`` = ``"time"``)
        or :func:`~roadcollab.reporting.fleet_report.write_fleet_estimates` (``"distance"``, with
        ``stretches``: the drives of every separate stretch of road), plus ``spikes_repaired`` per drive.

    Raises
    ------
    ParameterError
        An unusable ``out_dir`` (before anything is read) or bad input files
        (:class:`~roadcollab.errors.FileFormatError`); ``out_dir`` is untouched then.
    """
    from ..io.drives import common_time_grid, load_drives
    from ..io.drive_clean import clean_drive, cleaning_note
    from ..reporting.records import staged_output

    t0 = time.perf_counter()
    with staged_output(out_dir, NAME, drive_paths) as out:
        raw = load_drives(drive_paths, limits=limits)
        cleaned = [clean_drive(d) for d in raw]
        drives = [d for d, _ in cleaned]
        cleanings = [c for _, c in cleaned]
        notes = [cleaning_note(drives, cleanings)]
        described = [c.describe(d.sample_rate) for d, c in cleaned]
        if common_time_grid(drives) and not align:
            summary = _time_grid(drives, out, command=command, segment_length=segment_length, t0=t0, notes=notes,
                                 cleaning=described, guard=guard)
        else:
            summary = _distance_grid(drives, out, command=command, segment_length=segment_length, align=align,
                                     max_offset=max_offset, spacing=spacing, t0=t0, notes=notes, cleaning=described,
                                     guard=guard)
    return {**summary, "out_dir": str(out_dir), "spikes_repaired": [c.n_spikes for c in cleanings]}


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
    parser.add_argument("--out", type=out_path, required=True, metavar="DIR",
                        help="output folder: absent, empty or a previous estimate result (never a folder holding "
                             "other files or the drives); written at the end, a failed run leaves it untouched")
    parser.add_argument("--segment-length", type=SEGMENT_LENGTH, default=100.0, metavar="M",
                        help="IRI segment length of the fused elevation, m (default 100; "
                             f"{help_range(SEGMENT_LENGTH)}, and at least 10 --grid-step)")
    parser.add_argument("--align", action="store_true",
                        help="estimate each drive's start offset (GPS error) by cross-correlating the drives' "
                             "inversions on distance, apply it and write offsets.csv")
    parser.add_argument("--max-offset", type=MAX_OFFSET, default=10.0, metavar="M",
                        help="largest start offset between two drives searched with --align, m (default 10; "
                             f"{help_range(MAX_OFFSET)}, and at least 2 --grid-step)")
    parser.add_argument("--grid-step", type=GRID_STEP, default=0.05, metavar="M",
                        help="step of the distance grid for drives at different speeds, m (default 0.05; "
                             f"{help_range(GRID_STEP)})")
    add_guard_options(parser)
    add_limit_options(parser, "each drive CSV")
    add_check(parser, _check)


def add_guard_options(parser: argparse.ArgumentParser) -> None:
    """``--guard-road`` and the named opt-out ``--unguarded-receive`` (``estimate`` and ``vehicle``).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The parser the options are added to.
    """
    parser.add_argument("--guard-road", choices=("class", "own"), default="class",
                        help="road prior of the receiver guard every received message goes through: 'class' (the "
                             "ISO 8608 class the estimators are designed for, C; default) or 'own' (the vehicle's own "
                             "inversion)")
    parser.add_argument("--unguarded-receive", action="store_true",
                        help="apply received messages without the receiver guard (the paper's Algorithm 1; a "
                             "well-formed lie then steers the estimate); recorded in config.json")


def receiver_guard(args: argparse.Namespace) -> str | None:
    """The guard road prior of ``args``, None with ``--unguarded-receive``.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options of :func:`add_guard_options`.

    Returns
    -------
    str or None
    """
    return None if args.unguarded_receive else args.guard_road


def _check(args: argparse.Namespace) -> str | None:
    """The options together: segments and offsets against the grid step, and every --drive a regular file."""
    problem = check_segment_length(args.segment_length, args.grid_step, "--grid-step")
    if problem is None and args.max_offset < 2 * args.grid_step:
        problem = (f"argument --max-offset: expected at least 2 --grid-step ({2 * args.grid_step:g} m) to search, "
                   f"got {args.max_offset:g} m")
    return problem or check_file_options("--drive", args.drive, "drive CSV")


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
             "it), repairs isolated logger spikes and removes slow offsets such as gravity (both counted in the "
             "report), relays Algorithm 1 down the drives in the order given, fuses the estimates and looks for "
             "anomalies. Long drives are estimated in overlapping windows (memory stays bounded). A bad file is "
             "refused with one line naming the file, the line and the field.",
        writes="into --out (replaced as a whole at the end): road_estimates.csv, final_estimate.csv, "
               "anomalies.csv, iri.csv, offsets.csv (drives at different speeds/starts), figures, config.json, "
               "report.md.",
        example="roadcollab estimate --drive d1.csv --drive d2.csv --out results/road")
    add_estimate_arguments(p)
    return p


def _stretch_text(s: dict) -> str:
    g = s["drives"]
    return f"drive{'s' if len(g) > 1 else ''} {','.join(map(str, g))}: {s['start_m']:.1f}-{s['end_m']:.1f} m"


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
                               spacing=args.grid_step, guard=receiver_guard(args))
    for note in summary.get("notes", []):
        print(f"note: {note}")
    n = summary["n_drives"]
    stretches = summary.get("stretches") or []
    where = (f"{len(stretches)} separate stretches ({'; '.join(_stretch_text(s) for s in stretches)})"
             if len(stretches) > 1 else f"{summary['length_m']:.1f} m")
    print(f"estimated {plural(n, 'drive')} over {where} ({summary['grid']} grid); "
          f"wrote {args.out}/report.md")
    return 0
