"""``roadcollab bench``: per-segment cost of one vehicle, and its scaling with segment length."""

from __future__ import annotations

import argparse
import json

from ._common import command_parser, positive_int, print_table

__all__ = ["NAME", "add_parser", "run"]

NAME = "bench"
_QUICK_SIZES = (1000, 2000, 4000, 8000, 16000)
_SIZES = (1000, 2000, 4000, 8000, 16000, 32000, 64000)


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``bench`` subcommand and its options.

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
        subparsers, NAME, summary="per-segment cost of one vehicle, and its scaling with segment length",
        does="Times one vehicle's work per road segment for every privacy mechanism (single-threaded) and how the "
             "cost grows with the segment length.",
        writes="nothing: tables (or one JSON line with --json) on stdout.",
        example="roadcollab bench --quick --json")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.add_argument("--repeats", type=positive_int, default=30, help="timed segments per point (default 30)")
    p.add_argument("--quick", action="store_true", help="only up to 16k samples")
    return p


def run(args: argparse.Namespace, command_line: str) -> int:
    """Time the pipeline and print the record (one JSON line with ``--json``, else tables).

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options of :func:`add_parser`.
    command_line : str
        Unused (the benchmark writes no files).

    Returns
    -------
    int
        Exit status 0.
    """
    from ..experiments.bench import run_bench

    rec = run_bench(sizes=_QUICK_SIZES if args.quick else _SIZES, repeats=args.repeats)
    if args.json:
        print(json.dumps(rec))
        return 0
    print_table(f"ms per vehicle-segment ({rec['samples_per_segment']} samples, 1 thread)",
                ("mechanism", "ms / vehicle-segment"),
                [(m, f"{v:.2f}") for m, v in rec["ms_per_vehicle_segment_by_mechanism"].items()])
    print_table("scaling (cost per N log N relative to N = 4000)", ("N", "paper ms", "rel", "hardened ms", "rel"),
                [(str(s_["n_samples"]), f"{s_['ms_paper']:.2f}", f"{s_['paper_per_nlogn_rel']:.2f}",
                  f"{s_['ms_hardened']:.2f}", f"{s_['hardened_per_nlogn_rel']:.2f}") for s_ in rec["scaling"]])
    print(f"setup per vehicle: {rec['ms_per_vehicle_setup']:.1f} ms")
    return 0
