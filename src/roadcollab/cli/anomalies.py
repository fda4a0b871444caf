"""``roadcollab anomalies``: the road anomaly detection study (F1, position error, sweeps)."""

from __future__ import annotations

import argparse
from typing import Any

from ._arguments import NOISE, help_range, iso_class
from ._common import (input_paths, command_parser, add_dask_options, add_road_options, add_study_options, check_dask_options,
                      config_from_args, dask_options, plural, print_table, run_with_progress)

__all__ = ["NAME", "add_parser", "run"]

NAME = "anomalies"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``anomalies`` subcommand and its options.

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
        subparsers, NAME, summary="road anomaly detection study (F1, position error, sweeps)",
        does="Simulates roads with potholes and bumps, detects them in every estimator's road estimate and scores "
             "precision, recall, F1 and position error, with sweeps over anomaly depth and sensor noise.",
        writes="into --out (replaced as a whole at the end): detection.csv, the road map, F1 vs depth, F1 vs "
               "noise (each figure with its CSV), config.json, report.md.",
        example="roadcollab anomalies --runs 5 --no-sweeps --out results/anomalies")
    add_study_options(p, runs=20, runs_help="roads (default 20)", vehicles_help="fleet size (default 10)",
                      min_vehicles=2)
    p.add_argument("--noise", type=NOISE, default=None,
                   help=f"accelerometer noise std, m/s^2 (default 0.05; {help_range(NOISE)})")
    p.add_argument("--iso-class", type=iso_class, default=None,
                   help="ISO 8608 roughness class, A (smoothest) to H (default C)")
    p.add_argument("--no-sweeps", action="store_true", help="skip the depth and noise sweeps")
    add_road_options(p)
    add_dask_options(p)
    return p


def run(args: argparse.Namespace, command_line: str) -> int:
    """Run the anomaly study, write its outputs to ``args.out`` and print the detection table.

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
    from ..experiments.anomalies.config import AnomalyStudyConfig
    from ..experiments.anomalies.study import run_anomaly_study
    from ..reporting.anomaly_report import write_anomalies
    from ..reporting.records import staged_output

    # The study draws one road per run itself: the experiment describes a single run.
    ns = argparse.Namespace(runs=1, vehicles=args.vehicles, speed=args.speed, oracle=False,
                            road_profile=args.road_profile, noise=args.noise, iso_class=args.iso_class,
                            uncertainty=None, max_rows=args.max_rows, max_file_mb=args.max_file_mb)
    check_dask_options(args)
    with staged_output(args.out, NAME, input_paths(args)) as out:
        exp = config_from_args(ns)
        kw: dict[str, Any] = {"depths": (), "noise_levels": ()} if args.no_sweeps else {}
        cfg = AnomalyStudyConfig(experiment=exp, n_runs=args.runs, **kw)
        result, elapsed = run_with_progress(cfg.n_runs, NAME, lambda cb: run_anomaly_study(
            cfg, args.seed, progress=cb, **dask_options(args)))
        write_anomalies(result, out, command=command_line, elapsed=elapsed)
    print_table(f"Anomaly detection, {plural(cfg.n_runs, 'run')}, {elapsed:.1f} s",
                ("estimator", "precision", "recall", "F1", "median position error (m)"),
                [(r.estimator, f"{r.precision:.3f}", f"{r.recall:.3f}", f"{r.f1:.3f}",
                  f"{r.median_position_error_m:.3f}") for r in result.detection_rows])
    print(f"wrote {args.out}/report.md")
    return 0
