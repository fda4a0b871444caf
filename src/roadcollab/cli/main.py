"""Command-line interface ``roadcollab``.

Subcommands: ``reproduce`` (Figs. 4-7), ``sweep`` (where Algorithm 1 beats a single vehicle),
``attack`` (security study), ``anomalies``, ``calibrate-anomalies``, ``estimate`` (recorded drives),
``bench``, ``iri`` (International Roughness Index), ``message example``. Long work shows a progress bar.

Each subcommand is a module of this package with ``NAME``, ``add_parser(subparsers)`` and
``run(args, command_line)``; helpers they share are in :mod:`roadcollab.cli._common`.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from .. import __version__
from . import anomalies, attack, bench, calibrate, enroll, estimate, export, fleet, iri, message, reproduce, serve, \
    status, sweep, vehicle
from ._common import command_line

__all__ = ["main", "build_parser"]

# In the order of ``roadcollab --help``.
COMMANDS = (reproduce, attack, anomalies, calibrate, sweep, bench, estimate, iri, message, enroll, serve, vehicle, fleet,
            export, status)
_RUN = {module.NAME: module.run for module in COMMANDS}
_DESCRIPTION = """Privacy-preserving collaborative road estimation by networked vehicles (Gao, Li and Wang).

Vehicles drive the same road one after another; each estimates the road input from its accelerometers
and its own suspension model, and passes an obfuscated message to the next (Algorithm 1 with
Algorithm 2). The commands reproduce the paper's figures, study attacks and anomaly detection, and
estimate the road from recorded drives. Every command that writes takes --out and writes all its
results at once; 'roadcollab COMMAND --help' says what it writes."""
_EPILOG = """examples:
  roadcollab reproduce --runs 20 --out results/repro
  roadcollab estimate --drive d1.csv --drive d2.csv --out results/road"""


def build_parser() -> argparse.ArgumentParser:
    """The ``argparse`` parser of the ``roadcollab`` command.

    Subcommands ``reproduce``, ``sweep``, ``attack``, ``anomalies``, ``calibrate-anomalies``, ``bench``,
    ``estimate``, ``iri`` and ``message example``; the parsed subcommand is ``args.command``.

    Returns
    -------
    argparse.ArgumentParser
    """
    parser = argparse.ArgumentParser(prog="roadcollab", description=_DESCRIPTION, epilog=_EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
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
        ``ParameterError`` or ``FileFormatError``) or the system refuses a file operation
        (``OSError``); the message is printed to stderr on one line, without a traceback.

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
        if args.command != "message":
            _check_out_folder(getattr(args, "out", None))
        return run(args, command_line(argv))
    except ValueError as err:  # ParameterError / FileFormatError / MessageError: a clear message, no traceback
        print(f"roadcollab {args.command}: error: {_one_line(str(err))}", file=sys.stderr)
        return 2
    except OSError as err:  # e.g. the disk filled up while writing the results
        where = f"{err.filename}: " if getattr(err, "filename", None) else ""
        print(f"roadcollab {args.command}: error: {where}{_one_line(err.strerror or str(err))}", file=sys.stderr)
        return 2


def _check_out_folder(out) -> None:
    """Refuse an unusable ``--out`` folder before the command imports its study (a second or more):
    an existing non-folder, or a nearest existing ancestor that is not a writable folder. The
    command's staged output checks again when it creates its folder."""
    if out is None:
        return
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: expected a folder, got an existing file")
    parent = out.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"--out {out}: cannot write there ({parent} is not a writable folder)")


def _one_line(text: str, width: int = 2000) -> str:
    """``text`` on one line (newlines become spaces), cut to ``width`` characters."""
    text = " ".join(text.split())
    return text if len(text) <= width else text[:width] + " ..."


if __name__ == "__main__":
    sys.exit(main())
