"""``roadcollab reproduce``: Monte Carlo reproduction of the paper's Figs. 4-7."""

from __future__ import annotations

import argparse

from ._arguments import GAMMA, NOISE, UNCERTAINTY, count, help_range, iso_class
from ._common import (add_kernels_option, input_paths, command_parser, add_dask_options, add_road_options,
                      add_study_options, check_dask_options, config_from_args, dask_options, plural, print_table,
                      progress_bars)

_MEASURED_RUNS = count("number of runs", 0, 10_000)

__all__ = ["NAME", "add_parser", "run"]

NAME = "reproduce"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``reproduce`` subcommand and its options.

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
        subparsers, NAME, summary="Monte Carlo reproduction of the paper's Figs. 4-7",
        does="Simulates a fleet driving one road segment after another, runs every estimator (each vehicle's own "
             "observer and inversion, Algorithm 1 with and without privacy, the fused, centralized and oracle "
             "estimates) over --runs Monte Carlo runs and scores them on one band; with --measured-runs it also "
             "drives the shipped measured profile and compares the estimated with the true IRI.",
        writes="into --out (replaced as a whole at the end): Fig. 4 (every estimator), Figs. 5-7, the fusion "
               "figure, mse.csv, bound_check.csv, fleet.csv, a CSV beside every figure, config.json, report.md; with "
               "--measured-runs also mse_measured.csv and iri_measured.csv.",
        example="roadcollab reproduce --runs 20 --vehicles 5 --out results/repro")
    add_study_options(p, runs=100, runs_help="Monte Carlo runs (default 100)", vehicles_help="fleet size (default 10)")
    p.add_argument("--noise", type=NOISE, default=None,
                   help=f"accelerometer noise std, m/s^2 (default 0.05; {help_range(NOISE)})")
    p.add_argument("--uncertainty", type=UNCERTAINTY, default=None,
                   help=f"relative parameter uncertainty of each vehicle's model (default 0.10; "
                        f"{help_range(UNCERTAINTY)})")
    p.add_argument("--iso-class", type=iso_class, default=None,
                   help="ISO 8608 roughness class of the synthetic road, A (smoothest) to H (default C)")
    p.add_argument("--gamma", type=GAMMA, default=None,
                   help=f"observer parameter gamma of eq. 4 (default 512, the strongest single-vehicle observer; "
                        f"{help_range(GAMMA)})")
    p.add_argument("--oracle", action="store_true", help="use the true plants in T_j (analysis only)")
    p.add_argument("--redraw-fleet", action="store_true",
                   help="draw a new fleet for every run (statistics over fleets)")
    p.add_argument("--measured-runs", type=_MEASURED_RUNS, default=20,
                   help="also run this many runs on the shipped measured profile for the report (default 20, "
                        f"independent of --runs; 0: skip; ignored with --road-profile; {help_range(_MEASURED_RUNS)})")
    add_road_options(p)
    add_dask_options(p)
    add_kernels_option(p)
    return p


def _measured_config(args: argparse.Namespace):
    """The configuration of the extra runs on the shipped measured profile for the report, or None if not wanted.

    Parameters
    ----------
    args : argparse.Namespace
        The command's options (``--measured-runs``, ``--road-profile``, the fleet).

    Returns
    -------
    ExperimentConfig or None
        The fleet and its estimators are the reproduction's; the runs drive the packaged profile.
    """
    if args.road_profile is not None or args.measured_runs <= 0:
        return None
    margs = argparse.Namespace(**{**vars(args), "road_profile": "packaged", "runs": args.measured_runs})
    return config_from_args(margs)


def run(args: argparse.Namespace, command_line: str) -> int:
    """Run the reproduction, write its outputs to ``args.out`` and print the MSE table.

    The reproduction and its measured-profile runs share one pool and one fleet setup
    (:func:`~roadcollab.experiments.reproduction.study.run_reproductions`).

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
    from rich.console import Console

    from ..experiments.pipeline import PipelineCache
    from ..lti.kernels import kernel_path
    from ..experiments.reproduction.iri import IRI_SEGMENT_LENGTH
    from ..experiments.reproduction.study import run_reproductions
    from ..reporting.records import staged_output
    from ..reporting.reproduction_report import headline_table, write_reproduction

    check_dask_options(args)
    with staged_output(args.out, NAME, input_paths(args)) as out:
        cfg, mcfg = config_from_args(args), _measured_config(args)
        # (configuration, IRI segment length, bar label); the IRI is compared on the measured profile only
        studies = [(cfg, None, NAME)] + ([] if mcfg is None else [(mcfg, IRI_SEGMENT_LENGTH, "measured profile")])
        prog, callbacks = progress_bars([(c.n_runs, label) for c, _, label in studies])
        with prog:
            done = run_reproductions([c for c, _, _ in studies], args.seed, progress=callbacks, **dask_options(args),
                                     iri_segment_lengths=[iri for _, iri, _ in studies], cache=PipelineCache())
        (result, elapsed), measured = done[0], None
        if mcfg is not None:    # its wall time after the reproduction's last run (both share the pool)
            measured = (done[1][0], done[1][1] - elapsed)
        timings = {"workers": (args.workers or 1) if args.scheduler is None else args.scheduler,
                   "kernels": kernel_path(), "runs_s": elapsed,
                   "measured_runs_s": 0.0 if measured is None else measured[1]}
        summary = write_reproduction(result, out, command=command_line, elapsed=elapsed, measured=measured,
                                     timings=timings, workers=args.workers)   # --workers 2: figures on 2 cores
    headers, values = headline_table(result.table())
    print_table(f"MSE per vehicle ((m/s)^2), {plural(cfg.n_runs, 'run')}, {elapsed:.1f} s", headers,
                [(str(v[0]), *(f"{x:.3g}" for x in v[1:])) for v in values])
    ratio = summary["vehicle1_observer_over_algorithm1"]
    alg1 = ("Algorithm 1 needs at least 2 vehicles" if ratio is None else
            f"vehicle 1 online / Algorithm 1 (vehicles 2..{cfg.n_vehicles}): {ratio:.2f}x")
    Console().print(f"{alg1}; fused / centralized at vehicle {cfg.n_vehicles}: "
                    f"{summary['fused_over_centralized_last']:.2f}x; wrote {args.out}/report.md")
    return 0
