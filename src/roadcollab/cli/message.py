"""``roadcollab message example``: write a valid example wire message."""

from __future__ import annotations

import argparse

from ._common import out_path, add_seed_option, command_parser

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
    from ..wire.layout import MECHANISM_CODES

    p = command_parser(subparsers, NAME, summary="message utilities (see 'roadcollab message example --help')",
                       does="Tools for the versioned binary wire format that vehicles exchange.",
                       writes="see the subcommands.", example="roadcollab message example --out msg.bin")
    msub = p.add_subparsers(dest="message_command", required=True)
    q = command_parser(msub, "example", summary="write a valid example message",
                       does="Encodes one valid message of the chosen privacy mechanism, as a vehicle would send it.",
                       writes="the encoded message to --out (replaced only when complete).",
                       example="roadcollab message example --mechanism hardened --out msg.bin")
    q.add_argument("--out", type=out_path, required=True, help="output file (new, or an earlier example)")
    q.add_argument("--mechanism", choices=list(MECHANISM_CODES), default="paper",
                   help="none/paper: an exchange message (T, S, e, wf); hardened/fused: an inversion message (z); "
                        "secure_aggregation: a masked input, the round-2 message a vehicle sends the aggregator "
                        "(vehicle 1, session 0/0, 600 x 2 uint64 ring elements, uniform as a masked z is); "
                        "default paper")
    add_seed_option(q, "seed of the example's random draws")
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
    from ..reporting.output_folder import staged_file
    from ..wire.protocol import decode, write_example

    with staged_file(args.out, is_ours=_is_message) as tmp:
        n = write_example(tmp, mechanism=args.mechanism, seed=args.seed)
    msg = decode(args.out.read_bytes())
    print(f"wrote {n} bytes to {args.out}: {type(msg).__name__} (mechanism {msg.mechanism!r})")
    return 0


def _is_message(path) -> bool:
    """Does ``path`` start like a roadcollab message (so an earlier ``message example`` wrote it)?"""
    from ..wire.layout import MAGIC

    with open(path, "rb") as fh:
        return fh.read(len(MAGIC)) == MAGIC
