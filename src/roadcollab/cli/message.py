"""``roadcollab message example``: write a valid example wire message."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..wire.protocol import MECHANISM_CODES, decode, write_example
from ._common import nonneg_int

__all__ = ["NAME", "add_parser", "run"]

NAME = "message"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``message`` subcommand and its ``example`` subcommand.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        From ``ArgumentParser.add_subparsers``.

    Returns
    -------
    argparse.ArgumentParser
        The subcommand's parser.
    """
    p = subparsers.add_parser(NAME, help="message utilities")
    msub = p.add_subparsers(dest="message_command", required=True)
    q = msub.add_parser("example", help="write a valid example message",
                        description="Write a valid example wire message with random content and print what it is.")
    q.add_argument("--out", type=Path, required=True, help="output file")
    q.add_argument("--mechanism", choices=list(MECHANISM_CODES), default="paper",
                   help="none/paper: an exchange message (T, S, e, wf); hardened/fused: an inversion message (z); "
                        "secure_aggregation: a masked input, the round-2 message a vehicle sends the aggregator "
                        "(vehicle 1, session 0/0, 600 x 2 uint64 ring elements, uniform as a masked z is)")
    q.add_argument("--seed", type=nonneg_int, default=0)
    return p


def run(args: argparse.Namespace, command_line: str) -> int:
    """Write the example message of ``args.mechanism`` to ``args.out`` and print its type and size.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options of :func:`add_parser` (``example`` is the only message command).
    command_line : str
        Unused (the message records no command line).

    Returns
    -------
    int
        Exit status 0.
    """
    n = write_example(args.out, mechanism=args.mechanism, seed=args.seed)
    msg = decode(args.out.read_bytes())
    print(f"wrote {n} bytes to {args.out}: {type(msg).__name__} (mechanism {msg.mechanism!r})")
    return 0
