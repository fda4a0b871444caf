"""Command-line interface ``roadcollab``.

Subcommands: ``reproduce`` (Figs. 4-7), ``sweep`` (where Algorithm 1 beats a single vehicle),
``attack`` (security study), ``anomalies``, ``calibrate-anomalies``, ``estimate`` (recorded drives),
``bench``, ``iri`` (International Roughness Index), ``message example``. Long work shows a progress bar.

Each subcommand is a module of this package with ``NAME``, ``add_parser(subparsers)`` and
``run(args, command_line)``; helpers they share are in :mod:`roadcollab.cli._common`.
"""

from __future__ import annotations

import argparse
import sys

from .. import __version__
from . import anomalies, attack, bench, calibrate, estimate, iri, message, reproduce, sweep
from ._common import command_line

__all__ = ["main", "build_parser"]

# In the order of ``roadcollab --help``.
COMMANDS = (reproduce, attack, anomalies, calibrate, sweep, bench, estimate, iri, message)
_RUN = {module.NAME: module.run for module in COMMANDS}


def build_parser() -> argparse.ArgumentParser:
    """The ``argparse`` parser of the ``roadcollab`` command.

    Subcommands ``reproduce``, ``sweep``, ``attack``, ``anomalies``, ``calibrate-anomalies``, ``bench``,
    ``estimate``, ``iri`` and ``message example``; the parsed subcommand is ``args.command``.

    Returns
    -------
    argparse.ArgumentParser
    """
    parser = argparse.ArgumentParser(prog="roadcollab", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"roadcollab {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for module in COMMANDS:
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``roadcollab`` command: parse ``argv`` and run the subcommand.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status: 0 on success, 2 if the command rejects its input (a ``ValueError`` such as
        ``ParameterError``; the message is printed to stderr, without a traceback).

    Raises
    ------
    SystemExit
        From argparse, for ``--help``, ``--version`` and invalid arguments.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    run = _RUN.get(args.command)
    if run is None:
        parser.error(f"unknown command {args.command!r}")
        return 2
    try:
        return run(args, command_line(argv))
    except ValueError as err:  # ParameterError / MessageError: a clear message, no traceback
        print(f"roadcollab {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
