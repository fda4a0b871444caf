"""``roadcollab helper --folder DIR --broker URL``: a helper aggregator of a validated fleet."""

from __future__ import annotations

import argparse
import signal
import threading
from pathlib import Path

from ._common import command_parser

__all__ = ["NAME", "add_parser", "run"]

NAME = "helper"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``helper`` subcommand.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction

    Returns
    -------
    argparse.ArgumentParser
    """
    p = command_parser(
        subparsers, NAME, summary="a helper aggregator of a fleet enrolled with --aggregation validated",
        does="Runs one helper (aggregator B or C) of the fleet's validated sessions, for an operator other than "
             "the service's (e.g. the road agency): advertises its key, takes part in the coin toss of the proofs' "
             "randomness, checks its shares of every vehicle's proof, releases its sums only once every aggregator "
             "announced the same accepted set (at least k, once per session and phase, recorded before they are "
             "sent) and signs a phase's result only if every sum it holds a copy of agrees. Runs until "
             "SIGINT/SIGTERM.",
        writes="DIR/releases.sqlite (its release log, kept across restarts); one line per event on stdout.",
        example="roadcollab helper --folder fleet/helper --broker mqtt://127.0.0.1:1883")
    p.add_argument("--folder", required=True, metavar="DIR",
                   help="a helper folder 'roadcollab enroll --aggregation validated' writes (FLEET/helper or "
                        "FLEET/helper-c)")
    p.add_argument("--broker", required=True, metavar="URL", help="mqtt://HOST:PORT (or mqtts:// with --tls fleets)")
    p.add_argument("--quiet", action="store_true", help="print only the start and stop lines")
    return p


def run(args: argparse.Namespace, command_line: str) -> int:
    """Answer the fleet's validated sessions until SIGINT/SIGTERM.

    Parameters
    ----------
    args : argparse.Namespace
    command_line : str

    Returns
    -------
    int
        0 after a clean stop.
    """
    from ..errors import ParameterError
    from ..network.aggregation import validated_params
    from ..network.fleetdir import load_aggregation, load_login, load_plan
    from ..network.mqtt_client import MqttClient, parse_broker_url
    from ..network.mqtt_run import run_service
    from ..network.priohelper import HelperParty
    from ..network.priowire import AggregatorKeys
    from ..network.relaykey import RelayKey
    from ..privacy.secagg_store import ReleaseLog
    from ..wire.identity import FleetTrust, VehicleIdentity

    parse_broker_url(args.broker)
    folder = Path(args.folder)
    if not (folder / "x25519.key").is_file():
        raise ParameterError(f"--folder {folder}: no x25519.key (the helper folder of a fleet enrolled with "
                             "--aggregation validated)")
    plan, policy = load_plan(folder), load_aggregation(folder)
    if not policy.validated:
        raise ParameterError(f"--folder {folder}: fleet.toml's aggregation mode is {policy.mode!r}, not 'validated'")
    params = validated_params(plan, policy)
    keys = AggregatorKeys(VehicleIdentity.load(folder), RelayKey.load(folder / "x25519.key"))
    if keys.party not in params.helper_ids:
        raise ParameterError(f"--folder {folder}: its certificate is {keys.party!r}, expected one of "
                             f"{list(params.helper_ids)}")
    trust, login = FleetTrust.load(folder / "trust.toml"), load_login(folder / "broker.toml")
    log = ReleaseLog(folder / "releases.sqlite")
    party = HelperParty(f"rc/{plan.fleet_id}", params, trust, keys, log,
                        on_event=(lambda line: None) if args.quiet else (lambda line: print(line, flush=True)))
    stop, republish = threading.Event(), threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    client = MqttClient(args.broker, login, f"rc-{plan.fleet_id}-{keys.party}", on_connect=republish.set)
    for filt in party.subscriptions:
        client.subscribe(filt)
    try:
        client.connect()
        print(f"helper {keys.party} of fleet {plan.fleet_id!r} on {args.broker}: {params.phases} phases per "
              f"session, k={params.min_inputs}", flush=True)
        handled = run_service(party, client, stop, republish)
    finally:
        client.close()
        log.close()
    svc = party.service
    done, running = (0, 0) if svc is None else (len(svc.finished), len(svc.sessions))
    print(f"stopped: {handled} messages handled; sessions this run: {done} finished, {running} still open", flush=True)
    return 0
