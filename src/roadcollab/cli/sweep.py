"""``roadcollab sweep``: where Algorithm 1 beats a single vehicle, on a gamma x noise x uncertainty grid."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from ._arguments import GAMMA, NOISE, UNCERTAINTY, add_check, count, help_range, ranged_list
from ._common import (add_kernels_option, input_paths, MAX_VEHICLES, command_parser, add_dask_options,
                      add_out_option, add_seed_option, check_dask_options, dask_options, plural, print_table,
                      run_with_progress)

_RUNS = count("number of runs", 1, 1000)
_VEHICLES = count("fleet size", 2, MAX_VEHICLES)
_GAMMAS = ranged_list("observer gamma", GAMMA.range.low, GAMMA.range.high)
_NOISES = ranged_list("noise standard deviation", NOISE.range.low, NOISE.range.high, NOISE.range.unit)
_UNCERTAINTIES = ranged_list("relative uncertainty", UNCERTAINTY.range.low, UNCERTAINTY.range.high)
#: Grid points x runs: 2000 is a few hours serially (about 5 s per run-point under load).
_MOST_RUN_POINTS = 2000
#: Lengths of SweepConfig's default grids (gammas, noise stds, uncertainties), known without importing the
#: study (a second); tests/test_cli_arguments.py checks them against SweepConfig.
DEFAULT_GRID_SIZES = (5, 2, 2)


def _check(args: argparse.Namespace) -> str | None:
    """The grid's size: points (product of the three lists' lengths) x --runs at most 2000."""
    sizes = [len(v) if v is not None else d for v, d in zip((args.gammas, args.noise, args.uncertainty),
                                                            DEFAULT_GRID_SIZES)]
    total = sizes[0] * sizes[1] * sizes[2] * args.runs
    if total > _MOST_RUN_POINTS:
        return (f"arguments --gammas, --noise, --uncertainty, --runs: {sizes[0]} x {sizes[1]} x {sizes[2]} grid "
                f"points x {plural(args.runs, 'run')} = {total:,} runs, more than the {_MOST_RUN_POINTS:,} accepted")
    return None

if TYPE_CHECKING:     # annotation only: imported lazily in _config
    from ..experiments.sweep.config import SweepConfig

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
    p.add_argument("--runs", type=_RUNS, default=8,
                   help="Monte Carlo runs per grid point, each with a new fleet and road (default 8; "
                        f"{help_range(_RUNS)}; grid points x runs at most {_MOST_RUN_POINTS:,})")
    add_seed_option(p)
    p.add_argument("--vehicles", type=_VEHICLES, default=10, help=f"fleet size (default 10; {help_range(_VEHICLES)})")
    p.add_argument("--gammas", type=_GAMMAS, default=None, metavar="LIST",
                   help=f"observer parameters gamma, comma-separated (default 1,8,32,128,512; each "
                        f"{help_range(_GAMMAS)})")
    p.add_argument("--noise", type=_NOISES, default=None, metavar="LIST",
                   help=f"accelerometer noise stds, m/s^2, comma-separated (default 0.05,0.2; each "
                        f"{help_range(_NOISES)})")
    p.add_argument("--uncertainty", type=_UNCERTAINTIES, default=None, metavar="LIST",
                   help=f"relative parameter uncertainties, comma-separated (default 0.05,0.15; each "
                        f"{help_range(_UNCERTAINTIES)})")
    add_dask_options(p)
    add_kernels_option(p)
    add_check(p, _check)
    return p


def _config(args: argparse.Namespace) -> SweepConfig:
    """The sweep's grid and run counts; options not given keep the :class:`SweepConfig` defaults."""
    from ..experiments.sweep.config import SweepConfig

    kw = {key: values for key, values in (("gammas", args.gammas), ("sensor_noise_stds", args.noise),
                                          ("parameter_uncertainties", args.uncertainty)) if values is not None}
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
    from ..experiments.sweep.study import run_sweep
    from ..reporting.records import staged_output
    from ..reporting.sweep_report import write_sweep

    cfg = _config(args)
    check_dask_options(args)
    with staged_output(args.out, NAME, input_paths(args)) as out:
        result, elapsed = run_with_progress(len(cfg.points()) * cfg.n_runs, NAME,
                                            lambda cb: run_sweep(cfg, args.seed, progress=cb, **dask_options(args)))
        findings = write_sweep(result, out, command=command_line, elapsed=elapsed)
    print_table(f"Vehicle 1's observer vs Algorithm 1, {plural(cfg.n_runs, 'run')} per point, {elapsed:.1f} s",
                ("noise (m/s^2)", "uncertainty", f"smallest gamma within {findings[0].threshold:g}x",
                 f"Alg. 1 / observer at gamma {findings[0].largest_gamma:g}", "Alg. 1 wins at gamma"),
                [(f"{f.sensor_noise_std:g}", f"{f.parameter_uncertainty:g}",
                  "none" if f.smallest_gamma_within is None else f"{f.smallest_gamma_within:g}",
                  f"{f.algorithm1_over_observer_at_largest:.3g}",
                  ", ".join(f"{g:g}" for g in f.gammas_algorithm1_wins) or "none") for f in findings])
    print(f"wrote {args.out}/report.md")
    return 0
