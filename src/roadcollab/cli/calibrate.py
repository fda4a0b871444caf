"""``roadcollab calibrate-anomalies``: grid search of the anomaly detector's threshold and depth floor."""

from __future__ import annotations

import argparse
from typing import Any

from ._arguments import SEED_MAX, add_check, count, help_range, ranged
from ._common import (input_paths, MAX_VEHICLES, command_parser, add_dask_options, add_out_option, check_dask_options, dask_options,
                      plural, progress)

_RUNS_PER_SEED = count("number of roads", 1, 1000)
_VEHICLES = count("fleet size", 2, MAX_VEHICLES)
#: A detection's SNR (dimensionless): the grid searched by default is 3.5-5.5.
_SNR = ranged("SNR threshold", 0.5, 100)
#: Anomaly depths, mm: the default grid is 5-15 mm; a pothole deeper than 0.5 m is not a road.
_DEPTH_MM = ranged("depth", 0.1, 500, "mm")
_MOST_SEEDS = 1000
_MOST_GRID = 50


def _seeds(text: str) -> str:
    """argparse type: seeds ``a`` or ``a-b`` (comma-separated), each from 0 to 2^53, at most 1000 of them.

    The text is returned as typed (the run expands it); the check comes first so that a range such as
    ``0-99999999999`` is refused instead of being expanded into memory.
    """
    _count_seeds(text)
    return text


def _count_seeds(text: str) -> int:
    """How many seeds ``text`` names (see :func:`_seeds`); ``argparse.ArgumentTypeError`` if it is malformed."""
    n = 0
    for part in (t.strip() for t in text.split(",")):
        lo, sep, hi = part.partition("-")
        if not (part.isascii() and lo.isdigit() and (not sep or hi.isdigit())) or len(part) > 40:
            raise argparse.ArgumentTypeError(f"expected seeds such as 1000 or 1000-1004, got {part[:40]!r}")
        a, b = int(lo), int(hi if sep else lo)
        if b > SEED_MAX:
            raise argparse.ArgumentTypeError(f"expected seeds from 0 to {SEED_MAX:,}, got {b:,}")
        if b < a:
            raise argparse.ArgumentTypeError(f"expected an ascending range a-b, got {part!r}")
        n += b - a + 1
        if n > _MOST_SEEDS:
            raise argparse.ArgumentTypeError(f"expected at most {_MOST_SEEDS} seeds, got {part!r} and more")
    return n


def _check(args: argparse.Namespace) -> str | None:
    """The seeds and the grids together: at most 1000 seeds, at most 50 values per grid."""
    n = sum(_count_seeds(text) for text in args.seeds)
    if n > _MOST_SEEDS:
        return f"argument --seeds: expected at most {_MOST_SEEDS} seeds in all, got {n}"
    for option, grid in (("--snr-thresholds", args.snr_thresholds), ("--min-depths-mm", args.min_depths_mm)):
        if grid is not None and len(grid) > _MOST_GRID:
            return f"argument {option}: expected at most {_MOST_GRID} values, got {len(grid)}"
    return None

__all__ = ["NAME", "add_parser", "run"]

NAME = "calibrate-anomalies"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``calibrate-anomalies`` subcommand and its options.

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
        subparsers, NAME, summary="grid search of the anomaly detector's threshold and depth floor on training seeds",
        does="Runs the anomaly study on training seeds only (evaluation seeds are refused) for every pair of SNR "
             "threshold and minimum depth, and picks the best point.",
        writes="into --out (replaced as a whole at the end): calibration.csv, config.json, report.md.",
        example="roadcollab calibrate-anomalies --seeds 1000-1002 --runs-per-seed 4 --out results/calibration")
    add_out_option(p)
    p.add_argument("--seeds", nargs="+", type=_seeds, default=["1000-1004"],
                   help="training root seeds, integers or ranges a-b (default 1000-1004; evaluation seed 0 refused; "
                        f"0 to 2^53, at most {_MOST_SEEDS} seeds)")
    p.add_argument("--runs-per-seed", type=_RUNS_PER_SEED, default=8,
                   help=f"roads per seed (default 8; {help_range(_RUNS_PER_SEED)})")
    p.add_argument("--vehicles", type=_VEHICLES, default=10, help=f"fleet size (default 10; {help_range(_VEHICLES)})")
    p.add_argument("--snr-thresholds", type=_SNR, nargs="+", default=None,
                   help=f"snr_threshold grid (default 3.5 4 4.25 4.5 5 5.5; each {help_range(_SNR)}, "
                        f"at most {_MOST_GRID} values)")
    p.add_argument("--min-depths-mm", type=_DEPTH_MM, nargs="+", default=None,
                   help=f"min_depth grid, mm (default 5 7.5 10 12.5 15; each {help_range(_DEPTH_MM)}, "
                        f"at most {_MOST_GRID} values)")
    add_dask_options(p)
    add_check(p, _check)
    return p


def run(args: argparse.Namespace, command_line: str) -> int:
    """Run the grid search on the training seeds, write its outputs to ``args.out`` and print the best point.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options of :func:`add_parser`; ``min_depths_mm`` in mm.
    command_line : str
        The command line, recorded in ``config.json`` and ``report.md``.

    Returns
    -------
    int
        Exit status 0.
    """
    from ..experiments.anomalies.calibration import calibrate_anomalies
    from ..experiments.anomalies.calibration_config import AnomalyCalibrationConfig, parse_seeds
    from ..experiments.config import ExperimentConfig
    from ..reporting.calibration_report import write_calibration
    from ..reporting.records import staged_output

    kw: dict[str, Any] = {}   # grid overrides, by AnomalyCalibrationConfig field
    if args.snr_thresholds is not None:
        kw["snr_thresholds"] = tuple(args.snr_thresholds)
    if args.min_depths_mm is not None:
        kw["min_depths"] = tuple(d / 1000.0 for d in args.min_depths_mm)
    cfg = AnomalyCalibrationConfig(seeds=parse_seeds(args.seeds), runs_per_seed=args.runs_per_seed,
                                   experiment=ExperimentConfig(n_vehicles=args.vehicles, n_runs=1), **kw)
    n = len(cfg.seeds) * cfg.runs_per_seed
    check_dask_options(args)
    with staged_output(args.out, NAME, input_paths(args)) as out:
        prog, cb = progress(n, NAME)
        with prog:
            result = calibrate_anomalies(cfg, progress=cb, **dask_options(args))
        write_calibration(result, out, command=command_line)
    best = result.best
    print(f"best point: snr_threshold {best.snr_threshold:g}, min_depth {1000 * best.min_depth:g} mm, objective "
          f"{best.objective:.4f} ({plural(n, 'run')}, {result.elapsed_s:.1f} s); wrote {args.out}/report.md")
    return 0
