"""``roadcollab sweep``: where Algorithm 1 beats a single vehicle, on a gamma x noise x uncertainty grid."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from ..errors import ParameterError
from ._common import (command_parser, add_dask_options, add_out_option, check_dask_options, dask_options, nonneg_int, positive_int,
                      print_table, run_with_progress)

if TYPE_CHECKING:     # annotation only: imported lazily in _config
    from ..experiments.sweep_config import SweepConfig

__all__ = ["NAME", "add_parser", "run"]

NAME = "sweep"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``sweep`` subcommand and its options.

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
        subparsers, NAME, summary="where Algorithm 1 beats a single vehicle: gamma x noise x uncertainty grid",
        does="Compares vehicle 1's own observer with Algorithm 1 on a grid of observer parameters gamma, sensor "
             "noise levels and parameter uncertainties, a new fleet and road for every run.",
        writes="into --out (replaced as a whole at the end): sweep.csv, sweep.png, config.json, report.md.",
        example="roadcollab sweep --runs 4 --gammas 8,512 --noise 0.05 --out results/sweep")
    add_out_option(p)
    p.add_argument("--runs", type=positive_int, default=8,
                   help="Monte Carlo runs per grid point, each with a new fleet and road (default 8)")
    p.add_argument("--seed", type=nonneg_int, default=0, help="root seed (default 0)")
    p.add_argument("--vehicles", type=positive_int, default=10, help="fleet size (default 10, at least 2)")
    p.add_argument("--gammas", default=None, metavar="LIST",
                   help="observer parameters gamma, comma-separated (default 1,8,32,128,512)")
    p.add_argument("--noise", default=None, metavar="LIST",
                   help="accelerometer noise stds, m/s^2, comma-separated (default 0.05,0.2)")
    p.add_argument("--uncertainty", default=None, metavar="LIST",
                   help="relative parameter uncertainties, comma-separated (default 0.05,0.15)")
    add_dask_options(p)
    return p


def _floats(option: str, text: str) -> tuple[float, ...]:
    """The comma-separated numbers of ``option``; a ParameterError naming the option otherwise."""
    try:
        return tuple(float(x) for x in text.split(","))
    except ValueError as err:
        raise ParameterError(f"{option} must be comma-separated numbers such as 1,8,32, got {text!r}") from err


def _config(args: argparse.Namespace) -> SweepConfig:
    """The sweep's grid and run counts; options not given keep the :class:`SweepConfig` defaults."""
    from ..experiments.sweep_config import SweepConfig

    kw = {key: _floats(option, text) for key, option, text in (
        ("gammas", "--gammas", args.gammas), ("sensor_noise_stds", "--noise", args.noise),
        ("parameter_uncertainties", "--uncertainty", args.uncertainty)) if text is not None}
    return SweepConfig(n_vehicles=args.vehicles, n_runs=args.runs, **kw)


def run(args: argparse.Namespace, command_line: str) -> int:
    """Run the sweep, write its outputs to ``args.out`` and print one row per noise and uncertainty.

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
    from ..experiments.sweep import run_sweep
    from ..reporting.records import staged_output
    from ..reporting.sweep_report import write_sweep

    cfg = _config(args)
    check_dask_options(args)
    with staged_output(args.out) as out:
        result, elapsed = run_with_progress(len(cfg.points()) * cfg.n_runs, NAME,
                                            lambda cb: run_sweep(cfg, args.seed, progress=cb, **dask_options(args)))
        findings = write_sweep(result, out, command=command_line, elapsed=elapsed)
    print_table(f"Vehicle 1's observer vs Algorithm 1, {cfg.n_runs} runs per point, {elapsed:.1f} s",
                ("noise (m/s^2)", "uncertainty", f"smallest gamma within {findings[0].threshold:g}x",
                 f"Alg. 1 / observer at gamma {findings[0].largest_gamma:g}", "Alg. 1 wins at gamma"),
                [(f"{f.sensor_noise_std:g}", f"{f.parameter_uncertainty:g}",
                  "none" if f.smallest_gamma_within is None else f"{f.smallest_gamma_within:g}",
                  f"{f.algorithm1_over_observer_at_largest:.3g}",
                  ", ".join(f"{g:g}" for g in f.gammas_algorithm1_wins) or "none") for f in findings])
    print(f"wrote {args.out}/report.md")
    return 0
