"""``roadcollab vehicle --fleet DIR --id vK --drive FILE --broker URL``: one vehicle on the network."""

from __future__ import annotations

import argparse
import os
import signal
import threading
from pathlib import Path

from ._arguments import help_range, ranged
from ._common import add_limit_options, command_parser, file_limits
from .estimate import add_guard_options, receiver_guard

_TIMEOUT = ranged("timeout", 0.1, 86_400, "s")

__all__ = ["NAME", "add_parser", "run"]

NAME = "vehicle"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``vehicle`` subcommand.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction

    Returns
    -------
    argparse.ArgumentParser
    """
    p = command_parser(
        subparsers, NAME, summary="one vehicle: its drive's segments through the service",
        does="Reads the drive, inverts it, cuts it into the fleet's segments; for each takes the message "
             "waiting there, checks it, runs Algorithm 1, and publishes its signed contribution. In a fleet "
             "enrolled on a road (enroll --network) it first places the drive on that road by its GPS fixes "
             "and aligns it to the waiting messages. Exits 0 when "
             "the service has acknowledged every segment, 3 if --timeout passes first.",
        writes="nothing (messages to the broker; one line on stdout).",
        example="roadcollab vehicle --fleet fleet --id v1 --drive d1.csv --broker mqtt://127.0.0.1:1883")
    p.add_argument("--fleet", required=True, metavar="DIR", help="the fleet folder")
    p.add_argument("--id", required=True, metavar="VID", help="the vehicle id (a folder in DIR/vehicles)")
    p.add_argument("--drive", required=True, metavar="FILE", help="the drive CSV (parameters file beside it)")
    p.add_argument("--broker", required=True, metavar="URL", help="mqtt://HOST:PORT")
    p.add_argument("--timeout", type=_TIMEOUT, default=300.0, metavar="S",
                   help=f"give up after S seconds (default 300; {help_range(_TIMEOUT)})")
    add_guard_options(p)
    add_limit_options(p, "the drive CSV")
    return p


def _die_after_shares(rounds) -> None:
    """Fault injection for the tests (``ROADCOLLAB_TEST_DIE_AFTER=shares``): after dealing its shares in
    a round the vehicle answers nothing more there, and 1 s after it dealt them in the rounds of all its
    segments the process kills itself (SIGKILL): the dropout secure aggregation must survive."""
    inner, dealt = rounds.on_message, set()

    def on_message(topic, payload):
        if bytes(payload[:40]).find(b'"type":"') >= 0 and any(
                f'"type":"{k}"'.encode() in bytes(payload[:40]) for k in ("dealt", "survivors", "signatures")):
            return []
        out = inner(topic, payload)
        dealt.update(p.topic.split("/secagg/")[1].split("/")[0] for p in out if "/shares/" in p.topic)
        if out and len(dealt) == len(rounds.inputs):
            threading.Timer(1.0, lambda: os.kill(os.getpid(), signal.SIGKILL)).start()
        return out

    rounds.on_message = on_message


def _secure_side(folder, identity, trust, plan, policy):
    """``(RoundAgent, RelayKey)`` of a secure-aggregation fleet, ``(None, None)`` in the clear."""
    if not policy.secure:
        return None, None
    from ..network.relaykey import RelayKey
    from ..network.secround_agent import RoundAgent
    from ..privacy.secagg_store import SessionLedger

    relay = RelayKey.load(folder / "relay.key")
    if policy.validated:
        from ..network.aggregation import validated_params
        from ..network.prioagent import PrioAgent

        # One measurement per segment across restarts, as in the secure rounds.
        return PrioAgent(identity, trust, validated_params(plan, policy), SessionLedger(folder / "secagg_ledger.sqlite"),
                         f"rc/{plan.fleet_id}", {}), relay
    # One input per (segment, epoch) across restarts: the ledger lives with the vehicle's identity.
    rounds = RoundAgent(identity, trust, policy.spec, SessionLedger(folder / "secagg_ledger.sqlite"),
                        f"rc/{plan.fleet_id}", {})
    if os.environ.get("ROADCOLLAB_TEST_DIE_AFTER") == "shares":
        _die_after_shares(rounds)
    return rounds, relay


def run(args: argparse.Namespace, command_line: str) -> int:
    """Run one vehicle to its last acknowledgement.

    Parameters
    ----------
    args : argparse.Namespace
    command_line : str

    Returns
    -------
    int
        0 when done, 3 on timeout.
    """

    from ..errors import ParameterError
    from ..io.drive_clean import clean_drive
    from ..io.drives import load_drive
    from ..network.agent import VehicleAgent
    from ..network.fleetdir import load_aggregation, load_login, load_plan
    from ..network.mqtt_client import MqttClient, parse_broker_url
    from ..network.mqtt_run import run_vehicle
    from ..wire.identity import FleetTrust, VehicleIdentity, check_id

    parse_broker_url(args.broker)
    folder = Path(args.fleet) / "vehicles" / check_id("--id", args.id)
    if not folder.is_dir():
        raise ParameterError(f"--id {args.id}: no vehicle folder {folder} (enrolled ids are vehicles/v1..vN)")
    plan = load_plan(args.fleet)
    identity, trust = VehicleIdentity.load(folder), FleetTrust.load(folder / "trust.toml")
    login = load_login(folder / "broker.toml")
    # Cleaned exactly as ``estimate`` cleans it (slow offsets, isolated spikes): the network changes no estimate.
    drive, cleaning = clean_drive(load_drive(args.drive, limits=file_limits(args)))
    if cleaning.n_spikes:
        print(f"{args.id}: {cleaning.n_spikes} isolated spikes repaired", flush=True)
    policy = load_aggregation(args.fleet)
    rounds, relay = _secure_side(folder, identity, trust, plan, policy)
    index = int(args.id[1:]) - 1 if args.id[1:].isascii() and args.id[1:].isdigit() else 0
    if args.unguarded_receive:
        print(f"{args.id}: --unguarded-receive: waiting messages are applied without the receiver guard", flush=True)
    from ..network.fleetlanes import load_road, placed_engine

    # on the fleet's road, on every road of its network, or on the drive's own axis (network/fleetlanes.py)
    engine, road_fields, realign = placed_engine(drive, plan, load_road(args.fleet, plan), index,
                                                 guard=receiver_guard(args))
    agent = VehicleAgent(engine, identity, trust, hello_extra=road_fields, realign=realign, rounds=rounds,
                         relay_key=relay)

    def contributed() -> None:
        if policy.secure:     # 'roadcollab fleet' starts the next vehicle on this line
            print(f"{args.id}: {len(agent.segments)} segments contributed; in their aggregation rounds", flush=True)
    reconnected = threading.Event()
    client = MqttClient(args.broker, login, f"rc-{plan.fleet_id}-{args.id}", on_connect=reconnected.set)
    try:
        client.connect(timeout=args.timeout)
        reconnected.clear()
        ok = run_vehicle(agent, client, timeout=args.timeout, reconnected=reconnected, on_contributed=contributed)
    finally:
        client.close()
    refused = sorted(s for s, o in agent.outcomes.items() if o == "conflict")
    note = f"; dropped {len(agent.dropped)} waiting messages that did not verify" if agent.dropped else ""
    if not ok:
        left = (f"segments {sorted(agent.pending)} unacknowledged" if agent.pending or not agent.started else
                f"no aggregation round closed with its input on segments {agent.rounds_left}")
        print(f"{args.id}: timeout after {args.timeout:g} s with {left}{note}", flush=True)
        return 3
    if rounds is not None:
        note += f"; {len(rounds.closed)} aggregation rounds closed"
    print(f"{args.id}: {len(agent.segments)} segments done ({client.bytes_out} bytes sent"
          f"{', conflicts on ' + str(refused) if refused else ''}){note}", flush=True)
    return 0
