"""``roadcollab status --store FILE``: vehicles seen, segments done, messages refused and why."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import command_parser

__all__ = ["NAME", "add_parser", "run"]

NAME = "status"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``status`` subcommand.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction

    Returns
    -------
    argparse.ArgumentParser
    """
    p = command_parser(subparsers, NAME, summary="what a service store holds: vehicles, segments, refusals",
                       does="Reads the service's store (also while 'serve' runs) and prints its counts.",
                       writes="nothing.", example="roadcollab status --store road.sqlite")
    p.add_argument("--store", required=True, metavar="FILE", help="the service's SQLite file")
    return p


def run(args: argparse.Namespace, command_line: str) -> int:
    """Print the store's status.

    Parameters
    ----------
    args : argparse.Namespace
    command_line : str

    Returns
    -------
    int
        0.
    """

    from ..errors import ParameterError
    from ..network.store import ServiceStore

    if not Path(args.store).is_file():
        raise ParameterError(f"--store {args.store}: not found (expected the file 'roadcollab serve' writes)")
    store = ServiceStore(args.store)
    st = store.status()
    store.close()
    print(f"fleet {store.plan.fleet_id!r}: {st['vehicles']} vehicles seen, {st['segments']} segments with a fused "
          f"estimate, {st['contributions']} contributions applied, {st['duplicates']} copies applied once")
    for reason, k in sorted(st["refused"].items(), key=lambda kv: -kv[1]):
        print(f"  refused {k}: {reason}")
    return 0
