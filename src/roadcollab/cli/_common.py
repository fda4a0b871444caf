"""Helpers shared by the ``roadcollab`` subcommands: argument types, common options, progress, command line."""

from __future__ import annotations

import argparse
import dataclasses
import shlex
import textwrap
import time
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

import re

from ..errors import ParameterError
from ..io.limits import DEFAULT_MAX_FILE_MB, DEFAULT_MAX_ROWS, FileLimits

if TYPE_CHECKING:     # annotations only: the subcommands import these lazily (start-up time)
    from rich.progress import Progress

    from ..experiments.config import ExperimentConfig

__all__ = ["positive_int", "nonneg_int", "positive_float", "paillier_bits", "add_out_option", "add_dask_options",
           "add_road_options", "add_limit_options", "file_limits", "dask_options", "check_dask_options",
           "command_line", "progress", "run_with_progress", "print_table", "config_from_args"]

#: The shortest measured profile a simulated command accepts: lead-in + lead-out (15 m each), one metre
#: of slack and a scored segment of at least 20 m.
MIN_SCORED_M = 20.0
_MARGIN_M = 15.0
_ADDRESS = re.compile(r"(tcp|tls|inproc|ucx|ws|wss)://[^\s]+|[A-Za-z0-9_.\-]+:\d{1,5}")


# --- argument types ------------------------------------------------------------------------------

def _int_at_least(low: int, what: str) -> Callable[[str], int]:
    """argparse type: an integer >= ``low`` with a clear message otherwise."""
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError as err:
            raise argparse.ArgumentTypeError(f"expected a {what} integer, got {text!r}") from err
        if v < low:
            raise argparse.ArgumentTypeError(f"expected a {what} integer, got {v}")
        return v
    return parse


positive_int = _int_at_least(1, "positive")
nonneg_int = _int_at_least(0, "non-negative")


def positive_float(text: str) -> float:
    """argparse type: a positive finite number.

    Parameters
    ----------
    text : str
        The option's value as typed.

    Returns
    -------
    float

    Raises
    ------
    argparse.ArgumentTypeError
        Not a number, not positive, or infinite.
    """
    try:
        v = float(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from err
    if not v > 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {text!r}")
    return v


def paillier_bits(text: str) -> int:
    """argparse type: a Paillier modulus size, a multiple of 64 from 512 to 8192 bits.

    Parameters
    ----------
    text : str
        The option's value as typed.

    Returns
    -------
    int

    Raises
    ------
    argparse.ArgumentTypeError
        Not an integer, out of range or not a multiple of 64.
    """
    v = positive_int(text)
    if not (512 <= v <= 8192 and v % 64 == 0):
        raise argparse.ArgumentTypeError(f"expected a key size from 512 to 8192 bits in steps of 64, got {v}")
    return v


def command_parser(subparsers, name: str, *, summary: str, does: str, writes: str, example: str
                   ) -> argparse.ArgumentParser:
    """A subcommand parser whose ``--help`` says what it does, what it writes and one example.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        From ``ArgumentParser.add_subparsers``.
    name : str
        The subcommand.
    summary : str
        One line for ``roadcollab --help``.
    does, writes : str
        What the command does and what it writes (paragraphs of the description).
    example : str
        One example command line.

    Returns
    -------
    argparse.ArgumentParser
    """
    return subparsers.add_parser(name, help=summary, description=f"{does}\n\nWrites: {writes}",
                                 epilog=f"example:\n  {example}", formatter_class=_HelpFormatter)


class _HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the description's paragraphs (each wrapped at 100 columns) and the example as written."""

    def _fill_text(self, text, width, indent):
        return "\n\n".join(textwrap.fill(par, min(width, 100), initial_indent=indent, subsequent_indent=indent)
                            for par in text.split("\n\n")) if not text.startswith("example:") else text


# --- common options ------------------------------------------------------------------------------

def add_out_option(p: argparse.ArgumentParser) -> None:
    """``--out DIR`` (required): the folder every study writes its outputs to."""
    p.add_argument("--out", type=Path, required=True, help="output folder")


def add_study_options(p: argparse.ArgumentParser, *, runs: int, runs_help: str, vehicles_help: str) -> None:
    """``--runs``, ``--vehicles``, ``--seed`` and ``--out``, in that order (reproduce, attack, anomalies).

    Parameters
    ----------
    p : argparse.ArgumentParser
    runs : int
        Default of ``--runs``.
    runs_help, vehicles_help : str
        Help texts of ``--runs`` and ``--vehicles``.
    """
    p.add_argument("--runs", type=positive_int, default=runs, help=runs_help)
    p.add_argument("--vehicles", type=positive_int, default=10, help=vehicles_help)
    p.add_argument("--seed", type=nonneg_int, default=0, help="root seed (default 0)")
    add_out_option(p)


def add_dask_options(p: argparse.ArgumentParser) -> None:
    """``--workers N`` or ``--scheduler ADDRESS`` (mutually exclusive): where the runs are computed."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=positive_int, default=None,
                   help="run on a local process pool with N worker processes (results are identical)")
    g.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run on an existing Dask cluster, e.g. tcp://host:8786")


def add_road_options(p: argparse.ArgumentParser) -> None:
    """``--road-profile FILE``, ``--speed`` (m/s) and the file limits: the road the simulated fleet drives."""
    p.add_argument("--road-profile", metavar="FILE", default=None,
                   help="measured profile (rows 'distance_m elevation_m', uniform spacing, at least "
                        f"{2 * _MARGIN_M + 1 + MIN_SCORED_M:g} m long); 'packaged' for the shipped one")
    p.add_argument("--speed", type=positive_float, default=15.0, help="vehicle speed, m/s (default 15)")
    add_limit_options(p, "the --road-profile file")


def add_limit_options(p: argparse.ArgumentParser, what: str) -> None:
    """``--max-rows`` and ``--max-file-mb``: the largest input file read (checked before reading).

    Parameters
    ----------
    p : argparse.ArgumentParser
    what : str
        The files the limits apply to, for the help text.
    """
    p.add_argument("--max-rows", type=positive_int, default=DEFAULT_MAX_ROWS, metavar="N",
                   help=f"most data rows accepted in {what} (default {DEFAULT_MAX_ROWS:,})")
    p.add_argument("--max-file-mb", type=positive_float, default=DEFAULT_MAX_FILE_MB, metavar="MB",
                   help=f"size limit of {what} in MB, checked before reading (default {DEFAULT_MAX_FILE_MB:g})")


def file_limits(args: argparse.Namespace) -> FileLimits:
    """The :class:`~roadcollab.io.limits.FileLimits` of :func:`add_limit_options` (defaults if absent).

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    FileLimits
    """
    return FileLimits(max_rows=getattr(args, "max_rows", DEFAULT_MAX_ROWS),
                      max_file_mb=getattr(args, "max_file_mb", DEFAULT_MAX_FILE_MB))


def dask_options(args: argparse.Namespace) -> dict:
    """``{"workers": ..., "scheduler": ...}`` from :func:`add_dask_options`, for the study runners."""
    return {"workers": args.workers, "scheduler": args.scheduler}


def check_dask_options(args: argparse.Namespace, timeout: float = 5.0) -> None:
    """Refuse an unreachable ``--scheduler`` before any compute (a connection attempt of ``timeout`` s).

    Parameters
    ----------
    args : argparse.Namespace
        With ``scheduler`` (None: nothing to check).
    timeout : float
        Seconds to wait for the scheduler.

    Raises
    ------
    ParameterError
        The address is malformed or no scheduler answers there.
    """
    address = getattr(args, "scheduler", None)
    if address is None:
        return
    if not _ADDRESS.fullmatch(address):
        raise ParameterError(f"--scheduler must be an address such as tcp://host:8786, got {address!r}")
    from dask.distributed import Client

    try:
        Client(address, timeout=timeout).close()
    except (OSError, TimeoutError) as err:
        raise ParameterError(f"--scheduler {address}: no Dask scheduler answered within {timeout:g} s "
                             f"({type(err).__name__}: {err})") from None


# --- running -------------------------------------------------------------------------------------

def command_line(argv: Sequence[str]) -> str:
    """The command line as recorded in ``config.json`` and ``report.md``: ``roadcollab`` and the quoted arguments."""
    return "roadcollab " + " ".join(shlex.quote(a) for a in argv)


def progress(total: int, description: str) -> tuple[Progress, Callable[[int], None]]:
    """A rich progress bar (on stderr) and a callback that advances it.

    Parameters
    ----------
    total : int
        Number of steps.
    description : str
        Label left of the bar.

    Returns
    -------
    prog : rich.progress.Progress
        Use as a context manager around the work.
    advance : callable
        ``advance(done)`` sets the number of completed steps.
    """
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    prog = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    console=Console(stderr=True), transient=False)
    task = prog.add_task(description, total=total)
    return prog, (lambda done: prog.update(task, completed=done))


def run_with_progress(total: int, description: str, work: Callable[[Callable[[int], None]], object]
                      ) -> tuple[object, float]:
    """Run ``work(advance)`` under a progress bar (:func:`progress`).

    Parameters
    ----------
    total : int
        Number of steps the bar counts.
    description : str
        Label left of the bar.
    work : callable
        Called once with the bar's ``advance(done)`` callback; returns the result.

    Returns
    -------
    result : object
        What ``work`` returned.
    elapsed : float
        Wall time of ``work``, s.
    """
    prog, cb = progress(total, description)
    t0 = time.perf_counter()
    with prog:
        result = work(cb)
    return result, time.perf_counter() - t0


def print_table(title: str, columns: Sequence[str], rows: Sequence[Sequence[str]]) -> None:
    """Print a rich table with right-justified columns to stdout.

    Parameters
    ----------
    title : str
        Table title.
    columns : sequence of str
        Column headers.
    rows : sequence of sequence of str
        Cell texts, one sequence per row.
    """
    from rich.console import Console
    from rich.table import Table

    table = Table(title=title)
    for col in columns:
        table.add_column(col, justify="right", overflow="fold")
    for row in rows:
        table.add_row(*row)
    console = Console()
    # Piped or in a narrow terminal rich assumes 80 columns and cuts numbers to "0.0…": give the table
    # the width it needs (headers may wrap, numbers never).
    need = sum(max([len(c)] + [len(r[i]) for r in rows]) + 3 for i, c in enumerate(columns)) + 1
    if console.width < need:
        console = Console(width=min(need, 250))
    console.print(table)


# --- simulation options --------------------------------------------------------------------------

def config_from_args(args: argparse.Namespace) -> ExperimentConfig:
    """The :class:`~roadcollab.experiments.reproduction.ExperimentConfig` of the simulation options.

    Parameters
    ----------
    args : argparse.Namespace
        ``runs``, ``vehicles``, ``speed`` (m/s), ``oracle``, ``road_profile``, ``noise`` (m/s^2),
        ``iso_class``, ``uncertainty`` and optionally ``redraw_fleet`` and ``gamma``; None keeps the default.

    Returns
    -------
    ExperimentConfig

    Raises
    ------
    ParameterError
        ``--road-profile`` names no existing file, or a value the configuration rejects.
    """
    from ..experiments.config import ExperimentConfig
    from ..io.profiles import measured_road
    from ..models.vehicle import FleetSpec

    kw = dict(n_runs=args.runs, n_vehicles=args.vehicles, speed=args.speed, oracle=args.oracle,
              road_profile=args.road_profile, redraw_fleet=getattr(args, "redraw_fleet", False),
              profile_limits=file_limits(args))
    if args.noise is not None:
        kw["sensor_noise_std"] = args.noise
    if args.iso_class is not None:
        kw["iso_class"] = args.iso_class
    if getattr(args, "gamma", None) is not None:
        kw["gamma"] = args.gamma
    if args.uncertainty is not None:
        kw["fleet"] = dataclasses.replace(FleetSpec(), estimate_uncertainty=args.uncertainty)
    if args.road_profile is not None and args.road_profile != "packaged" and not Path(args.road_profile).is_file():
        raise ParameterError(f"--road-profile must be an existing file, got {args.road_profile!r}")
    if args.road_profile is not None:
        # A measured profile covers a fixed stretch: score as much of it as fits.
        length = measured_road(None if args.road_profile == "packaged" else args.road_profile, rng=0,
                               limits=kw["profile_limits"]).length
        need = 2 * _MARGIN_M + 1.0 + MIN_SCORED_M
        if length < need:
            raise ParameterError(f"{args.road_profile}: the profile covers {length:.4g} m; a simulated run needs at "
                                 f"least {need:g} m ({_MARGIN_M:g} m lead-in, {MIN_SCORED_M:g} m scored, "
                                 f"{_MARGIN_M:g} m lead-out, 1 m slack)")
        kw["segment_length"] = min(300.0, length - 2 * _MARGIN_M - 1.0)
    return ExperimentConfig(**kw)
