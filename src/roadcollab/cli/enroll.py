"""``roadcollab enroll --fleet DIR --vehicles N``: a fleet's authority, vehicle identities and broker logins."""

from __future__ import annotations

import argparse

from ._arguments import count, help_range, ranged
from ._common import GRID_STEP, MAX_VEHICLES, SEGMENT_LENGTH, command_parser

_VEHICLES = count("number of vehicles", 1, MAX_VEHICLES)
_ROUND = count("vehicles per round", 2, 1000)
_CLIP = ranged("clip", 1e-6, 1e3, "m")
_COLLUDERS = count("colluders", 0, 999)
_MIN_SPEED = ranged("slowest speed", 0.5, 60, "m/s")
_DEVIATION = ranged("deviation", 1e-6, 1e3, "m")
_PHASES = count("phases", 0, 32)
_RESOLUTION = ranged("resolution", 1e-9, 1.0, "m")
_AGGREGATORS = count("number of aggregators", 2, 3)

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
        writes="--fleet DIR: fleet.toml, authority/, vehicles/vK/, service/broker.toml, broker/; with --aggregation "
               "validated also the service's aggregator identity and key in service/ and the helpers' folders "
               "helper/ and helper-c/ (hand each to its operator: 'roadcollab helper --folder DIR/helper').",
        example="roadcollab enroll --fleet fleet --vehicles 4 --min-speed 12")
    p.add_argument("--fleet", required=True, metavar="DIR", help="the fleet folder (created)")
    p.add_argument("--vehicles", required=True, type=_VEHICLES, metavar="N", help=f"number of vehicles ({help_range(_VEHICLES)})")
    p.add_argument("--fleet-id", default="fleet", metavar="ID", help="fleet name, topic prefix rc/ID (default fleet)")
    p.add_argument("--min-speed", type=_MIN_SPEED, default=10.0, metavar="M/S",
                   help="slowest speed the fleet admits, m/s: fixes the wavenumber band edge 0.5 Hz / M/S "
                        f"(estimate takes it from the slowest drive; default 10; {help_range(_MIN_SPEED)})")
    _add_road_options(p)
    p.add_argument("--segment-length", type=SEGMENT_LENGTH, default=100.0, metavar="M",
                   help=f"segment length (default 100; {help_range(SEGMENT_LENGTH)})")
    p.add_argument("--grid-step", type=GRID_STEP, default=0.05, metavar="M",
                   help=f"step of the distance grid (default 0.05, as estimate; {help_range(GRID_STEP)})")
    p.add_argument("--tls", action="store_true",
                   help="the broker listens with TLS only: a fleet CA and the broker's certificate are written, and "
                        "clients connect with mqtts://HOST:PORT (default: no TLS, for loopback)")
    p.add_argument("--tls-host", action="append", default=[], metavar="NAME",
                   help="with --tls: a host name or address the broker is reached by, besides 127.0.0.1 and "
                        "localhost (repeat)")
    g = p.add_argument_group("fusion (fixed for the fleet: the service does not choose it)")
    g.add_argument("--aggregation", choices=("clear", "secure", "validated"), default="clear",
                   help="clear: the service sums the inversions it receives; secure: vehicles send the next "
                        "vehicle's message sealed to the fleet and fuse each segment by secure aggregation, so "
                        "the service learns only sums; validated: as secure, but each segment's sum comes from "
                        "phased validated sessions with helper aggregators ('roadcollab helper', see --aggregators), "
                        "in which every input is proven inside --clip and its deviations inside --deviation, so no "
                        "vehicle can move the result far (default clear)")
    g.add_argument("--round-size", type=_ROUND, default=None, metavar="N",
                   help=f"secure: vehicles invited to a round (default K; at most 2T-C-1; {help_range(_ROUND)})")
    g.add_argument("--min-inputs", type=_ROUND, default=5, metavar="K",
                   help=f"secure: fewest inputs whose sum is revealed (default 5; {help_range(_ROUND)})")
    g.add_argument("--threshold", type=_ROUND, default=None, metavar="T",
                   help=f"secure: Shamir threshold, T <= K (default K; {help_range(_ROUND)})")
    g.add_argument("--max-colluders", type=_COLLUDERS, default=0, metavar="C",
                   help=f"secure: vehicles that may collude with the service, C < T; validated: lying vehicles the phase "
                        f"schedule is built for (at least 1; K > 2C) (default 0; {help_range(_COLLUDERS)})")
    g.add_argument("--clip", type=_CLIP, default=1.0, metavar="M",
                   help=f"secure: public bound on every elevation in a round, m (default 1; {help_range(_CLIP)})")
    g.add_argument("--deviation", type=_DEVIATION, default=0.01, metavar="M",
                   help="validated: public bound on an honest vehicle's rms deviation from a segment's mean, m; the "
                        f"later phases' l2 ball is M sqrt(2 points) (default 0.01; {help_range(_DEVIATION)})")
    g.add_argument("--phases", type=_PHASES, default=0, metavar="K",
                   help=f"validated: phases per session (default 0: from --clip and --deviation; {help_range(_PHASES)})")
    g.add_argument("--resolution", type=_RESOLUTION, default=2.0 ** -12, metavar="M",
                   help=f"validated: fixed-point step of the proofs, m (default 2^-12; {help_range(_RESOLUTION)})")
    g.add_argument("--aggregators", type=_AGGREGATORS, default=3, metavar="A",
                   help="validated: 3, the service and two helpers run by two other operators, so that one "
                        "aggregator that deviates is caught; 2, one helper, where privacy of the later phases needs "
                        "both aggregators to follow the protocol (docs/security-secagg.md) "
                        f"(default 3; {help_range(_AGGREGATORS)})")
    return p


def _add_road_options(p) -> None:
    """``--network FILE --road-id ID``: a fleet on a road (network/fleetroad.py)."""
    p.add_argument("--network", metavar="FILE", default=None,
                   help="road network GeoJSON (as 'roadcollab map --network'), copied into the fleet: with "
                        "--road-id, the vehicles place their GPS drives on that road and 'serve --roads' writes "
                        "its segments' geometry; without, on every road and direction they travel (default: no "
                        "road, the drives' own distance axis)")
    p.add_argument("--road-id", metavar="ID", default=None,
                   help="the one road of --network the fleet surveys, in its forward direction (default: every "
                        "road, both directions)")


def _road_of(args) -> tuple[dict, bytes | None]:
    """The plan's road fields and the network file's bytes of ``--network``/``--road-id`` (({}, None) without)."""
    from ..errors import ParameterError

    if args.network is None and args.road_id is not None:
        raise ParameterError("--road-id needs --network (the fleet's road in its network)")
    if args.network is None:
        return {}, None
    from ..geo.network import read_network
    from ..network.fleetlanes import ALL_ROADS
    from ..network.fleetroad import check_road, file_sha256

    network_roads = read_network(args.network)
    if args.road_id is None:
        with open(args.network, "rb") as fh:
            network = fh.read()
        return {"road_id": ALL_ROADS, "road_sha256": file_sha256(args.network)}, network
    check_road(network_roads, args.road_id, "--road-id")
    with open(args.network, "rb") as fh:
        network = fh.read()
    return {"road_id": args.road_id, "road_sha256": file_sha256(args.network)}, network


def _write_road(args, plan, network: bytes | None) -> str:
    """The network's copy in the new fleet folder (never replacing a file); the note for the summary line."""
    if network is None:
        return ""
    from ..network.fleetroad import ROAD_FILE

    with open(f"{args.fleet}/{ROAD_FILE}", "xb") as fh:
        fh.write(network)
    if plan.road_id == "*":
        return f" on every road of {args.network}"
    return f" on road {plan.road_id!r} of {args.network}"


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
    from ..errors import ParameterError
    from ..network.aggregation import AggregationPolicy
    from ..network.fleetdir import enroll
    from ..network.plan import RoadPlan
    from ..wire.identity import check_id

    road, network = _road_of(args)
    plan = RoadPlan(fleet_id=check_id("--fleet-id", args.fleet_id), spacing=args.grid_step,
                    segment_length=args.segment_length, min_speed=args.min_speed, **road)
    k = args.min_inputs
    t = k if args.threshold is None else args.threshold
    try:
        policy = AggregationPolicy(mode=args.aggregation, round_size=k if args.round_size is None else args.round_size,
                                   min_inputs=k, threshold=t, max_colluders=args.max_colluders, clip_m=args.clip,
                                   deviation_m=args.deviation, phases=args.phases, resolution_m=args.resolution,
                                   aggregators=args.aggregators)
    except ParameterError as err:
        raise ParameterError(f"--round-size/--min-inputs/--threshold/--max-colluders/--clip/--deviation/--phases/"
                             f"--resolution/--aggregators: {err}") from None
    if args.tls_host and not args.tls:
        raise ParameterError("--tls-host: needs --tls")
    ids = enroll(args.fleet, args.vehicles, plan, policy, tls_hosts=args.tls_host if args.tls else None)
    on = _write_road(args, plan, network)
    how = (f"; secure aggregation, rounds of {policy.round_size} (k={k}, t={t}, c={policy.max_colluders})"
           if policy.secure else "")
    if policy.validated:
        from ..network.aggregation import validated_params, validated_schedule

        from ..network.fleetdir import HELPER_FOLDERS

        params = validated_params(plan, policy)
        folders = " and ".join(f"{args.fleet}/{HELPER_FOLDERS[h]}" for h in params.helper_ids)
        how = (f"; validated aggregation with {policy.aggregators} aggregators, sessions of {policy.round_size} "
               f"(k={k}, {params.phases} phases); the helpers' folders: {folders}")
        if policy.aggregators == 2:
            how += ("; note: with 2 aggregators, privacy of the later phases needs both to follow the protocol "
                    "(one that deviates can steer the centres the vehicles clip around)")
        need = validated_schedule(plan, policy)
        if policy.phases and policy.phases < need:
            how += (f"; note: --phases {policy.phases} is below the {need} that work off one vehicle's phase-1 shift "
                    "(a lying vehicle keeps part of it)")
    tls = "; the broker listens with TLS (clients use mqtts://)" if args.tls else ""
    print(f"enrolled fleet {plan.fleet_id!r} with {len(ids)} vehicles ({ids[0]}..{ids[-1]}) in {args.fleet}{on}{how}"
          f"{tls}")
    return 0
