"""Helpers shared by the ``roadcollab`` subcommands: argument types, common options, progress, command line."""

from __future__ import annotations

import argparse
import dataclasses
import shlex
import textwrap
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

import re

from ..errors import FileFormatError, ParameterError
from ..io.limits import DEFAULT_MAX_FILE_MB, DEFAULT_MAX_ROWS, FileLimits, check_regular_file
from ._arguments import MAX_FILE_MB, MAX_ROWS, SEED, SPEED, WORKERS, add_check, count, help_range, plural, ranged
from ._outputs import input_paths, out_path
from ._progress import progress, progress_bars, run_with_progress
from ._table import print_table

if TYPE_CHECKING:     # annotations only: the subcommands import these lazily (start-up time)
    from ..experiments.config import ExperimentConfig

__all__ = ["input_paths", "out_path", "positive_int", "nonneg_int", "positive_float", "paillier_bits", "add_out_option",
           "add_dask_options", "add_road_options", "add_kernels_option", "BATCH_KERNELS", "add_limit_options",
           "add_seed_option", "file_limits", "dask_options", "check_dask_options", "command_line", "progress",
           "progress_bars", "run_with_progress", "print_table", "plural", "config_from_args"]

#: The shortest measured profile a simulated command accepts: lead-in + lead-out (15 m each), one metre
#: of slack and a scored segment of at least 20 m.
MIN_SCORED_M = 20.0
_MARGIN_M = 15.0
#: The most vehicles an experiment accepts (ExperimentConfig).
MAX_VEHICLES = 1000
#: IRI segments: 1 m (shorter is the Golden Car's own response, not the road's) to 100 km.
SEGMENT_LENGTH = ranged("segment length", 1, 100_000, "m")
#: Distance grid of drives at different speeds: 5 mm (finer than any tyre resolves) to 1 m (the
#: coarsest profile spacing read).
GRID_STEP = ranged("grid step", 0.005, 1, "m")
#: Start offsets between drives (GPS error): 0.1 m to 1 km.
MAX_OFFSET = ranged("largest offset", 0.1, 1000, "m")
#: A segment spans at least this many samples of the profile or grid it averages.
MIN_SAMPLES_PER_SEGMENT = 10
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
    """``--out DIR`` (required): the folder every study writes its outputs to (absent, empty or a previous
    result of the same command: README "Output folders")."""
    p.add_argument("--out", type=out_path, required=True,
                   help="output folder: absent, empty, or a previous result of this command (never a folder "
                        "holding other files)")


def add_study_options(p: argparse.ArgumentParser, *, runs: int, runs_help: str, vehicles_help: str,
                      min_runs: int = 1, max_runs: int = 10_000, min_vehicles: int = 1) -> None:
    """``--runs``, ``--vehicles``, ``--seed`` and ``--out``, in that order (reproduce, attack, anomalies).

    Parameters
    ----------
    p : argparse.ArgumentParser
    runs : int
        Default of ``--runs``.
    runs_help, vehicles_help : str
        Help texts of ``--runs`` and ``--vehicles`` (the range is appended).
    min_runs, max_runs : int
        Range of ``--runs``.
    min_vehicles : int
        Smallest ``--vehicles`` (the largest is the 1000 an experiment accepts).
    """
    runs_type = count("number of runs", min_runs, max_runs)
    vehicles_type = count("fleet size", min_vehicles, MAX_VEHICLES)
    p.add_argument("--runs", type=runs_type, default=runs, help=f"{runs_help}; {help_range(runs_type)}")
    p.add_argument("--vehicles", type=vehicles_type, default=10,
                   help=f"{vehicles_help}; {help_range(vehicles_type)}")
    add_seed_option(p)
    add_out_option(p)


def add_seed_option(p: argparse.ArgumentParser, what: str = "root seed") -> None:
    """``--seed`` (default 0), from 0 to 2^53 (``config.json`` records it; JSON keeps such integers exact)."""
    p.add_argument("--seed", type=SEED, default=0, help=f"{what} (default 0; {help_range(SEED)})")


def add_dask_options(p: argparse.ArgumentParser) -> None:
    """``--workers N`` or ``--scheduler ADDRESS`` (mutually exclusive): where the runs are computed."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=WORKERS, default=None, metavar="N",
                   help="run on a local process pool with N worker processes (results are identical; "
                        f"{help_range(WORKERS)})")
    g.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run on an existing Dask cluster, e.g. tcp://host:8786")


#: Where no ``--kernels`` and no ``ROADCOLLAB_KERNELS`` say otherwise, the commands that run Algorithm 2 many
#: times (``reproduce``, ``attack``, ``sweep``, ``bench``) use the compiled kernels: a fresh installation's first
#: run compiles for 6-10 s once (docs/speed.md), every later run loads them from disk.
BATCH_KERNELS = "compiled"


def add_kernels_option(p: argparse.ArgumentParser) -> None:
    """``--kernels {compiled,reference}`` of the commands that run Algorithm 2 many times."""
    p.add_argument("--kernels", choices=("compiled", "reference"), default=None,
                   help="kernels: compiled (numba; the default unless ROADCOLLAB_KERNELS says otherwise; without "
                        "numba the numpy path runs) or reference (numpy only). Results agree to round-off")


def add_road_options(p: argparse.ArgumentParser) -> None:
    """``--road-profile FILE``, ``--speed`` (m/s) and the file limits: the road the simulated fleet drives."""
    p.add_argument("--road-profile", metavar="FILE", default=None,
                   help="measured profile (rows 'distance_m elevation_m' or 'distance_m left_m right_m', uniform "
                        f"spacing, at least {2 * _MARGIN_M + 1 + MIN_SCORED_M:g} m long); 'packaged' for the "
                        "shipped one")
    p.add_argument("--speed", type=SPEED, default=15.0,
                   help=f"vehicle speed, m/s (default 15; {help_range(SPEED)}, road vehicles)")
    add_limit_options(p, "the --road-profile file")
    add_check(p, lambda args: check_file_options("--road-profile", [args.road_profile], "profile file",
                                                 keep=("packaged",)))


def check_file_options(option: str, paths, what: str, keep: Sequence[str] = ()) -> str | None:
    """The first of ``paths`` that is not an existing, readable regular file, as an argument error; None if all are.

    Parameters
    ----------
    option : str
        The option naming the files (``"--drive"``).
    paths : sequence of str or None
        The values given (None entries are skipped).
    what : str
        What the files are (``"drive CSV"``).
    keep : sequence of str
        Values that name no file (``"packaged"``).

    Returns
    -------
    str or None
        ``"argument --drive: <path>: ..."`` (see :func:`~roadcollab.io.limits.check_regular_file`).
    """
    for path in paths or ():
        if path is None or path in keep:
            continue
        try:
            check_regular_file(Path(path), what)
        except FileFormatError as err:
            return f"argument {option}: {err}"
    return None


def check_segment_length(segment_length: float, spacing: float, spacing_name: str) -> str | None:
    """A segment shorter than ten sample spacings as an argument error; None if it is long enough.

    Parameters
    ----------
    segment_length : float
        ``--segment-length``, m.
    spacing : float
        Sample spacing of the profile or grid, m.
    spacing_name : str
        Where the spacing comes from (``"--grid-step"``, ``"the profile's spacing"``).

    Returns
    -------
    str or None
    """
    need = MIN_SAMPLES_PER_SEGMENT * spacing
    if segment_length < need * (1 - 1e-9):
        return (f"argument --segment-length: expected at least {MIN_SAMPLES_PER_SEGMENT} times {spacing_name} "
                f"({need:g} m), got {segment_length:g} m")
    return None


def add_limit_options(p: argparse.ArgumentParser, what: str) -> None:
    """``--max-rows`` and ``--max-file-mb``: the largest input file read (checked before reading).

    Parameters
    ----------
    p : argparse.ArgumentParser
    what : str
        The files the limits apply to, for the help text.
    """
    p.add_argument("--max-rows", type=MAX_ROWS, default=DEFAULT_MAX_ROWS, metavar="N",
                   help=f"most data rows accepted in {what} (default {DEFAULT_MAX_ROWS:,}; {help_range(MAX_ROWS)})")
    p.add_argument("--max-file-mb", type=MAX_FILE_MB, default=DEFAULT_MAX_FILE_MB, metavar="MB",
                   help=f"size limit of {what} in MB, checked before reading (default {DEFAULT_MAX_FILE_MB:g}; "
                        f"{help_range(MAX_FILE_MB)})")


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


# --- simulation options --------------------------------------------------------------------------

def config_from_args(args: argparse.Namespace) -> ExperimentConfig:
    """The :class:`~roadcollab.experiments.reproduction.study.ExperimentConfig` of the simulation options.

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
    if args.road_profile is not None and args.road_profile != "packaged":
        check_regular_file(Path(args.road_profile), "--road-profile file")
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
