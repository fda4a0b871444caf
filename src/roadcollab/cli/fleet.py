"""``roadcollab fleet --fleet DIR --drive FILE [--drive FILE] --broker URL [--concurrent]``: one vehicle process per drive."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

from ._arguments import help_range
from ._common import command_parser
from .vehicle import _TIMEOUT

__all__ = ["NAME", "add_parser", "run"]

NAME = "fleet"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``fleet`` subcommand.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction

    Returns
    -------
    argparse.ArgumentParser
    """
    p = command_parser(
        subparsers, NAME, summary="run one 'roadcollab vehicle' process per drive (v1 drives the first)",
        does="Starts 'roadcollab vehicle' for each drive, vehicle vK for the K-th drive: one after another "
             "(each waits for the previous one's last acknowledgement, as 'estimate' takes the drives in "
             "order), or all at once with --concurrent. Exits 0 if every vehicle finished.",
        writes="nothing (each vehicle prints one line).",
        example="roadcollab fleet --fleet fleet --drive d1.csv --drive d2.csv --broker mqtt://127.0.0.1:1883")
    p.add_argument("--fleet", required=True, metavar="DIR", help="the fleet folder")
    p.add_argument("--drive", action="append", required=True, metavar="FILE", help="a drive CSV; repeat in order")
    p.add_argument("--broker", required=True, metavar="URL", help="mqtt://HOST:PORT")
    p.add_argument("--concurrent", action="store_true", help="start every vehicle at once")
    p.add_argument("--timeout", type=_TIMEOUT, default=300.0, metavar="S",
                   help=f"per vehicle (default 300; {help_range(_TIMEOUT)})")
    return p


def run(args: argparse.Namespace, command_line: str) -> int:
    """Run the vehicles.

    Parameters
    ----------
    args : argparse.Namespace
    command_line : str

    Returns
    -------
    int
        0 if every vehicle exited 0, else 3.
    """

    from ..errors import ParameterError
    from ..network.fleetdir import load_aggregation
    from ..network.mqtt_client import parse_broker_url

    parse_broker_url(args.broker)
    n = len(list((Path(args.fleet) / "vehicles").glob("v*")))
    if len(args.drive) > n:
        raise ParameterError(f"--drive: {len(args.drive)} drives but fleet {args.fleet} has {n} vehicles")
    for d in args.drive:
        if not Path(d).is_file():
            raise ParameterError(f"--drive {d}: not found (expected a drive CSV)")

    def cmd(k, d):
        return [sys.executable, "-m", "roadcollab.cli.main", "vehicle", "--fleet", args.fleet, "--id", f"v{k + 1}",
                "--drive", d, "--broker", args.broker, "--timeout", str(args.timeout)]

    if args.concurrent:
        procs = [subprocess.Popen(cmd(k, d)) for k, d in enumerate(args.drive)]
        codes = [p.wait(timeout=args.timeout + 60) for p in procs]
    elif load_aggregation(args.fleet).secure:
        # A round needs its vehicles online together: start the next vehicle once this one's segments are
        # acknowledged (its line "... contributed"), and keep them all running until their rounds close.
        piped: list[subprocess.Popen[str]] = []
        for k, d in enumerate(args.drive):
            q = subprocess.Popen(cmd(k, d), stdout=subprocess.PIPE, text=True, bufsize=1)
            piped.append(q)
            for line in q.stdout or ():     # ends at the line, or when the vehicle exits
                print(line, end="", flush=True)
                if " contributed" in line:
                    break
        for q in piped:
            for line in q.stdout or ():
                print(line, end="", flush=True)
        codes = [q.wait(timeout=args.timeout + 60) for q in piped]
    else:
        codes = []
        for k, d in enumerate(args.drive):
            codes.append(subprocess.run(cmd(k, d), timeout=args.timeout + 60).returncode)
    bad = [f"v{k + 1}" for k, c in enumerate(codes) if c != 0]
    print(f"fleet: {len(codes) - len(bad)} of {len(codes)} vehicles done" + (f"; failed: {bad}" if bad else ""))
    return 0 if not bad else 3
