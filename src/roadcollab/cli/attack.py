"""``roadcollab attack``: the security study (attacks, linkability, exactness, baselines)."""

from __future__ import annotations

import argparse

from ._arguments import count, help_range
from ._common import (add_kernels_option, input_paths, command_parser, add_dask_options, add_study_options,
                      check_dask_options, dask_options, paillier_bits, plural, print_table, run_with_progress)

#: Vehicles the replica attacks target (AttackStudyConfig.replica_targets): the fleet needs at least as many.
_REPLICA_TARGETS = 3
_REPLICA_RUNS = count("number of segments", 1, 100)
_POISONING_RUNS = count("number of runs", 1, 100)

__all__ = ["NAME", "add_parser", "run"]

NAME = "attack"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``attack`` subcommand and its options.

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
        subparsers, NAME, summary="security study: attacks, linkability, exactness, baselines",
        does="Attacks the messages of Algorithm 1 with and without Algorithm 2 (structural, signal, physical-fit "
             "and replica attacks on each sender's model), measures linkability, the exactness of the privacy "
             "mechanisms and what hostile messages do to a guarded receiver and to the fleet's fusion, and "
             "compares with differential privacy (composed over segments), Paillier encryption, AEAD and secure "
             "aggregation.",
        writes="into --out (replaced as a whole at the end): attack.csv (with the replica attacker), exactness.csv, "
               "linkability.csv, poisoning.csv, baselines.csv (DP, Paillier, AEAD, secure aggregation), "
               "dp_composition.csv, frontier.csv, Figs. 8-12, config.json, report.md.",
        example="roadcollab attack --runs 5 --paillier-bits 1024 --out results/attack")
    add_study_options(p, runs=20, runs_help="segments (default 20)", min_runs=2, max_runs=1000,
                      vehicles_help=f"fleet size (default 10; the replica attacks target {_REPLICA_TARGETS} vehicles)",
                      min_vehicles=_REPLICA_TARGETS)
    p.add_argument("--paillier-bits", type=paillier_bits, default=2048,
                   help="Paillier key size, bits (512-8192 in steps of 64; default 2048)")
    p.add_argument("--replica-runs", type=_REPLICA_RUNS, default=3,
                   help=f"segments of the replica attacks (default 3; linked attacks need 3; "
                        f"{help_range(_REPLICA_RUNS)})")
    p.add_argument("--poisoning-runs", type=_POISONING_RUNS, default=2,
                   help=f"runs of the poisoning measurements (default 2; {help_range(_POISONING_RUNS)})")
    add_dask_options(p)
    add_kernels_option(p)
    return p


def run(args: argparse.Namespace, command_line: str) -> int:
    """Run the security study, write its outputs to ``args.out`` and print the attack table.

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
    from ..experiments.config import ExperimentConfig
    from ..experiments.security.replica import replica_fit_count
    from ..experiments.security.study import AttackStudyConfig, run_attack_study
    from ..reporting.attack_report import write_attack
    from ..reporting.records import staged_output

    cfg = AttackStudyConfig(experiment=ExperimentConfig(n_vehicles=args.vehicles, n_runs=1), n_runs=args.runs,
                            paillier_bits=args.paillier_bits, replica_runs=args.replica_runs,
                            poisoning_runs=args.poisoning_runs)
    check_dask_options(args)
    with staged_output(args.out, NAME, input_paths(args)) as out:
        steps = cfg.n_runs + replica_fit_count(cfg)
        result, elapsed = run_with_progress(steps, NAME, lambda cb: run_attack_study(
            cfg, args.seed, progress=cb, **dask_options(args)))
        write_attack(result, out, command=command_line, elapsed=elapsed)
    print_table(f"Attacks on S_j's poles, {plural(cfg.n_runs, 'segment')}, {elapsed:.1f} s",
                ("mechanism", "attack", "road", "segments", "median rel. pole error", "success rate"),
                [(r.mechanism, r.attack, r.road, str(r.segments), f"{r.median_rel_pole_error:.3g}",
                  f"{r.success_rate:.2f}") for r in result.attack_rows])
    print(f"wrote {args.out}/report.md")
    return 0
