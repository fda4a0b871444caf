"""``roadcollab enroll --fleet DIR --vehicles N``: a fleet's authority, vehicle identities and broker logins."""

from __future__ import annotations

import argparse

from ._common import command_parser, positive_float

__all__ = ["NAME", "add_parser", "run"]

NAME = "enroll"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``enroll`` subcommand.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction

    Returns
    -------
    argparse.ArgumentParser
    """
    p = command_parser(
        subparsers, NAME, summary="create a fleet: authority key, vehicle identities, broker logins and ACL",
        does="Creates a fleet folder: an Ed25519 fleet authority, one identity (key + certificate) per vehicle in "
             "vehicles/v1..vN with its broker.toml (MQTT username and password), the service's login, and the "
             "broker's password files and topic ACL for the embedded broker and for Mosquitto. Never replaces "
             "an existing fleet.",
        writes="--fleet DIR: fleet.toml, authority/, vehicles/vK/, service/broker.toml, broker/.",
        example="roadcollab enroll --fleet fleet --vehicles 4 --min-speed 12")
    p.add_argument("--fleet", required=True, metavar="DIR", help="the fleet folder (created)")
    p.add_argument("--vehicles", required=True, type=int, metavar="N", help="number of vehicles (1..10000)")
    p.add_argument("--fleet-id", default="fleet", metavar="ID", help="fleet name, topic prefix rc/ID (default fleet)")
    p.add_argument("--min-speed", type=positive_float, default=10.0, metavar="M/S",
                   help="slowest speed the fleet admits, m/s: fixes the wavenumber band edge 0.5 Hz / M/S "
                        "(estimate takes it from the slowest drive; default 10)")
    p.add_argument("--segment-length", type=positive_float, default=100.0, metavar="M",
                   help="segment length, m (default 100)")
    p.add_argument("--grid-step", type=positive_float, default=0.05, metavar="M",
                   help="step of the distance grid, m (default 0.05, as estimate)")
    return p


def run(args: argparse.Namespace, command_line: str) -> int:
    """Enroll the fleet and print one line.

    Parameters
    ----------
    args : argparse.Namespace
    command_line : str

    Returns
    -------
    int
        0.
    """
    from ..network.fleetdir import enroll
    from ..network.plan import RoadPlan
    from ..wire.identity import check_id

    plan = RoadPlan(fleet_id=check_id("--fleet-id", args.fleet_id), spacing=args.grid_step,
                    segment_length=args.segment_length, min_speed=args.min_speed)
    ids = enroll(args.fleet, args.vehicles, plan)
    print(f"enrolled fleet {plan.fleet_id!r} with {len(ids)} vehicles ({ids[0]}..{ids[-1]}) in {args.fleet}")
    return 0
