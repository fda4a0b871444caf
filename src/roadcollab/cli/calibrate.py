"""``roadcollab calibrate-anomalies``: grid search of the anomaly detector's threshold and depth floor."""

from __future__ import annotations

import argparse

from ._common import (input_paths, command_parser, add_dask_options, add_out_option, check_dask_options, dask_options, positive_float, positive_int,
                      progress)

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
    p.add_argument("--seeds", nargs="+", default=["1000-1004"],
                   help="training root seeds, integers or ranges a-b (default 1000-1004; evaluation seed 0 refused)")
    p.add_argument("--runs-per-seed", type=positive_int, default=8, help="roads per seed (default 8)")
    p.add_argument("--vehicles", type=positive_int, default=10, help="fleet size (default 10, at least 2)")
    p.add_argument("--snr-thresholds", type=positive_float, nargs="+", default=None,
                   help="snr_threshold grid (default 3.5 4 4.25 4.5 5 5.5)")
    p.add_argument("--min-depths-mm", type=positive_float, nargs="+", default=None,
                   help="min_depth grid, mm (default 5 7.5 10 12.5 15)")
    add_dask_options(p)
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
    from ..experiments.anomaly_calibration import calibrate_anomalies
    from ..experiments.calibration_config import AnomalyCalibrationConfig, parse_seeds
    from ..experiments.config import ExperimentConfig
    from ..reporting.calibration_report import write_calibration
    from ..reporting.records import staged_output

    kw = {}
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
          f"{best.objective:.4f} ({n} runs, {result.elapsed_s:.1f} s); wrote {args.out}/report.md")
    return 0
