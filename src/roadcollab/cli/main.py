"""Command-line interface ``roadcollab``.

Subcommands: ``reproduce`` (Figs. 4-7), ``sweep`` (where Algorithm 1 beats a single vehicle),
``attack`` (security study), ``anomalies``, ``calibrate-anomalies``, ``estimate`` (recorded drives),
``bench``, ``iri`` (International Roughness Index), ``message example``. Long work shows a progress bar.

Each subcommand is a module of this package with ``NAME``, ``add_parser(subparsers)`` and
``run(args, command_line)``; helpers they share are in :mod:`roadcollab.cli._common`.
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import os
import signal
import sys
from pathlib import Path

from .. import __version__
from ..lti.kernels import environment_kernels, use_kernels
from . import anomalies, attack, bench, calibrate, enroll, estimate, export, fleet, helper, iri, message, reproduce, \
    serve, simulate_drives, status, sweep, vehicle
from . import map as map_cmd
from ._arguments import CommandParser
from ._common import BATCH_KERNELS, command_line

__all__ = ["main", "console_main", "build_parser"]

# In the order of ``roadcollab --help``.
COMMANDS = (reproduce, attack, anomalies, calibrate, sweep, bench, simulate_drives, estimate, map_cmd, iri, message,
            enroll, serve, helper, vehicle, fleet, export, status)
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
    parser = CommandParser(prog="roadcollab", description=_DESCRIPTION, epilog=_EPILOG,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"roadcollab {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=CommandParser)
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
        (``OSError``); the message is printed to stderr on one line, without a traceback. 130 after
        SIGINT (Ctrl-C) and 143 after SIGTERM, with one line saying what happened to ``--out``.

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
    out = getattr(args, "out", None)
    had_results = out is not None and Path(out).is_dir() and any(Path(out).iterdir())
    previous = signal.signal(signal.SIGTERM, _terminated)
    try:
        _check_out(args)
        kernels = _kernels(args)
        with contextlib.nullcontext() if kernels is None else use_kernels(kernels):
            _compile_alongside(args, kernels)
            return run(args, command_line(argv))
    except (KeyboardInterrupt, Terminated, SystemError) as err:
        cause = _interruption(err)
        if cause is None:
            raise
        status = 143 if isinstance(cause, Terminated) else 130
        where = "" if out is None else (f"; the previous results in {out} are untouched" if had_results
                                        else f"; nothing was written to {out}")
        print(f"roadcollab {args.command}: interrupted{where}", file=sys.stderr)
        return status
    except ValueError as err:  # ParameterError / FileFormatError / MessageError: a clear message, no traceback
        print(f"roadcollab {args.command}: error: {_one_line(str(err))}", file=sys.stderr)
        return 2
    except OSError as err:  # e.g. the disk filled up while writing the results
        where = f"{err.filename}: " if getattr(err, "filename", None) else ""
        print(f"roadcollab {args.command}: error: {where}{_one_line(err.strerror or str(err))}", file=sys.stderr)
        return 2
    finally:
        signal.signal(signal.SIGTERM, previous)


def _kernels(args: argparse.Namespace) -> str | None:
    """The kernel path of a command with ``--kernels`` (``reproduce``, ``attack``, ``sweep``, ``bench``):
    the option, else ``ROADCOLLAB_KERNELS``, else :data:`~roadcollab.cli._common.BATCH_KERNELS`; None for the
    other commands (they keep the library's default, the numpy path, unless ``ROADCOLLAB_KERNELS`` is set: a
    vehicle process starts faster on it)."""
    if not hasattr(args, "kernels"):
        return None
    return args.kernels or environment_kernels() or BATCH_KERNELS


def _compile_alongside(args: argparse.Namespace, kernels: str | None) -> None:
    """On the compiled path with an empty kernel cache, compile the sender's kernels in a second
    process while the command compiles the receiver's (:mod:`roadcollab.experiments.bench.warm`): a
    fresh installation's first ``paper`` run compiles in about half the time. Only for the commands
    with ``--kernels`` (they run the ``paper`` mechanism): on the compiled path, and for ``bench`` always
    (it times ``paper`` on both paths; ``bench --scale``'s Dask workers load what it compiled)."""
    if args.command != "bench" and kernels != "compiled":
        return
    from ..experiments.bench.warm import start_background_compile
    start_background_compile()


class Terminated(BaseException):
    """SIGTERM received: unwinds like ``KeyboardInterrupt`` (staging folders removed, workers stopped)."""


def _terminated(signum, frame) -> None:
    raise Terminated()


def _interruption(err: BaseException) -> BaseException | None:
    """The ``KeyboardInterrupt`` or :class:`Terminated` that ``err`` is or was caused by, else None.

    A signal's handler runs at the next Python instruction, and after a compiled kernel that is often
    inside numba's callback that boxes its result (``_numba_unpickle``): the interrupt then reaches the
    caller as a ``SystemError`` raised from it (measured: SIGTERM during ``reproduce``, in
    ``_block_form``).
    """
    seen: set[int] = set()
    cur: BaseException | None = err
    while cur is not None and id(cur) not in seen:
        if isinstance(cur, (KeyboardInterrupt, Terminated)):
            return cur
        seen.add(id(cur))
        cur = cur.__cause__ or cur.__context__
    return None


def _check_out(args: argparse.Namespace) -> None:
    """Refuse an unusable or unsafe ``--out`` before the command imports its study (a second or more);
    the command's staged output checks again when it creates its folder
    (:mod:`roadcollab.reporting.output_folder`)."""
    from ..reporting.output_folder import check_output_file, check_output_folder
    from ._common import input_paths

    out = getattr(args, "out", None)
    if out is None:
        return
    if args.command == "message":
        check_output_file(out, is_ours=lambda p: True)  # the command checks the file's content itself
    else:
        check_output_folder(out, args.command, input_paths(args))


def _one_line(text: str, width: int = 2000) -> str:
    """``text`` on one line (newlines become spaces), cut to ``width`` characters."""
    text = " ".join(text.split())
    return text if len(text) <= width else text[:width] + " ..."


def console_main() -> None:
    """The ``roadcollab`` command: :func:`main`, then an exit that skips the interpreter's teardown.

    Once the command has returned and every exit handler has run (its files are closed, its workers
    stopped), the process ends with ``os._exit``: deallocating numba's compiled modules and the rest
    object by object took 0.3-0.5 s of every run's wall time (measured, docs/speed.md), for memory the
    operating system frees at once. ``--help``, ``--version`` and argparse's errors exit as usual.
    """
    status = main()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):   # a closed pipe (roadcollab ... | head) or stream
            pass
    atexit._run_exitfuncs()     # what a normal exit runs: weakref finalizers, multiprocessing, logging
    os._exit(status)


if __name__ == "__main__":
    console_main()
