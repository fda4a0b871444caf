"""``roadcollab serve --fleet DIR --store FILE [--listen HOST:PORT | --broker URL]``: the roadside service."""

from __future__ import annotations

import argparse
import os
import signal
import socket
import threading
from pathlib import Path

from ._arguments import help_range, ranged
from ._common import command_parser

_ROUND_TIMEOUT = ranged("round timeout", 0.1, 3600, "s")
_ROUND_WAIT = ranged("round wait", 0.0, 86_400, "s")

__all__ = ["NAME", "add_parser", "run"]

NAME = "serve"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``serve`` subcommand.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction

    Returns
    -------
    argparse.ArgumentParser
    """
    p = command_parser(
        subparsers, NAME, summary="the roadside service (starts the embedded MQTT broker unless --broker)",
        does="Starts the embedded MQTT broker (amqtt) on --listen unless --broker names one, receives the "
             "vehicles' signed contributions, orders the vehicles on each segment, keeps the fused estimate per "
             "segment and the message waiting there, and refuses (with a reason in the store) whatever does not "
             "verify. Runs until SIGINT/SIGTERM; restarted on the same store it continues.",
        writes="--store FILE (SQLite, or PostgreSQL for a URL; each message's effect one transaction); one line per event on stdout.",
        example="roadcollab serve --fleet fleet --store road.sqlite --listen 127.0.0.1:1883")
    p.add_argument("--fleet", required=True, metavar="DIR", help="the fleet folder from 'roadcollab enroll'")
    p.add_argument("--store", required=True, metavar="FILE",
                   help="the service's SQLite file (created if missing) or a PostgreSQL URL "
                        "postgresql://user@host/db (the same tables; several serve --shared may share it)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--listen", default="127.0.0.1:1883", metavar="HOST:PORT",
                   help="where the embedded broker listens (default 127.0.0.1:1883)")
    g.add_argument("--broker", metavar="URL", help="use this broker instead (mqtt://HOST:PORT), e.g. Mosquitto")
    p.add_argument("--shared", action="store_true",
                   help="subscribe through the shared subscription $share/FLEET/... (several serve instances "
                        "against one broker split the messages)")
    p.add_argument("--roads", metavar="URL", default=None,
                   help="road-condition store to keep up to date while serving (IRI per 100 m with its interval "
                        "and vehicles, fused profile, anomalies; history kept): an SQLite file, sqlite:///path or "
                        "postgresql://user@host/db; the store 'roadcollab map' writes; a fleet enrolled on a road "
                        "writes map's segments with their geometry)")
    p.add_argument("--map", nargs="?", const="127.0.0.1:8765", default=None, metavar="HOST:PORT",
                   help="serve the live map of --roads (the page 'roadcollab map' writes, redrawn as segments "
                        "finish) on HOST:PORT (default with no value 127.0.0.1:8765, loopback only)")
    p.add_argument("--round-timeout", type=_ROUND_TIMEOUT, default=20.0, metavar="S",
                   help="secure aggregation: close a round's phase with the vehicles that answered after S seconds "
                        f"(default 20; {help_range(_ROUND_TIMEOUT)})")
    p.add_argument("--round-wait", type=_ROUND_WAIT, default=60.0, metavar="S",
                   help="secure aggregation: open a round with fewer than the fleet's round size (at least k) when "
                        f"a vehicle has waited S seconds (default 60; {help_range(_ROUND_WAIT)})")
    p.add_argument("--quiet", action="store_true", help="print only the start and stop lines")
    return p


def _road_outputs(args, store, command_line: str, log, map_at):
    """``(RoadSync or None, LiveMap or None, the service's hook or None)`` of ``--roads`` / ``--map``.

    Parameters
    ----------
    args : argparse.Namespace
    store : ServiceStore
        The service's store (closed here if the road store or the live map cannot be opened).
    command_line : str
        Recorded as the road store rows' source.
    log : callable
        One line per event.
    map_at : (str, int) or None
        Where the live map listens.
    """
    if args.roads is None:
        return None, None, None
    from ..network.fleetlanes import load_road
    from ..network.livemap import LiveMap
    from ..network.roadsync import RoadSync
    from ..store import RoadStore

    sync = live = None
    try:
        road = load_road(args.fleet, store.plan)        # a fleet on a road or a network: segments with their geometry
        sync = RoadSync(RoadStore.open(args.roads), store, source=command_line, min_interval_s=1.0, road=road)
        if map_at is not None:
            live = LiveMap(args.roads, *map_at).start()
            print(f"live map of {args.roads} on {live.url}", flush=True)
    except BaseException:
        if sync is not None:
            sync.roads.close()
        store.close()
        raise

    def on_fused(segment: int, st) -> None:
        before = (sync.written_segments, sync.written_anomalies)
        sync(segment, st)
        if (sync.written_segments, sync.written_anomalies) != before:
            log(f"road store {args.roads}: +{sync.written_segments - before[0]} segment estimates, "
                f"+{sync.written_anomalies - before[1]} anomalies")

    return sync, live, on_fused


def _validated_rounds(args, store, trust, policy, plan, log):
    """The service as the leading aggregator of a validated fleet (``FLEET/service``: its identity, X25519 key
    and release log)."""
    from ..errors import ParameterError
    from ..network.priowire import AggregatorKeys
    from ..network.relaykey import RelayKey
    from ..network.validated_rounds import ValidatedRounds
    from ..privacy.secagg_store import ReleaseLog
    from ..wire.identity import VehicleIdentity

    if args.shared:
        raise ParameterError("--shared: a validated fleet's sessions do not move between services (the leader's "
                             "shares are in memory), so one service serves it")
    folder = Path(args.fleet) / "service"
    if not (folder / "x25519.key").is_file():
        raise ParameterError(f"--fleet {args.fleet}: no service/x25519.key (enroll --aggregation validated writes it)")
    keys = AggregatorKeys(VehicleIdentity.load(folder), RelayKey.load(folder / "x25519.key"))
    return ValidatedRounds(store, trust, policy, f"rc/{plan.fleet_id}", keys=keys,
                           release_log=ReleaseLog(folder / "releases.sqlite"), log=log,
                           phase_timeout_s=args.round_timeout, round_wait_s=args.round_wait)


def _service(args, store, trust, policy, plan, command_line: str, map_at, status):
    """The service with its event log, road outputs and (secure aggregation) rounds."""
    from ..network.service import Service

    def log(line: str) -> None:
        """One line per event, with the running counts (vehicles seen, segments done, rounds, refusals)."""
        if not args.quiet:
            status.event(line, store.status())

    sync, live, on_fused = _road_outputs(args, store, command_line, log, map_at)
    rounds = None
    if policy.validated:
        return Service(store, trust, log=log, on_fused=on_fused, rounds=_validated_rounds(args, store, trust, policy, plan,
                                                                                       log)), sync, live
    if policy.secure:
        from ..network.rounds import SecureRounds

        # Several services on one store hold rounds under their own names; one service keeps its name across
        # restarts and so adopts its open rounds at once (network/rounds.py).
        owner = f"serve-{socket.gethostname()}-{os.getpid()}" if args.shared else "serve"
        rounds = SecureRounds(store, trust, policy, f"rc/{plan.fleet_id}", log=log,
                              phase_timeout_s=args.round_timeout, round_wait_s=args.round_wait, owner=owner)
    return Service(store, trust, log=log, on_fused=on_fused, rounds=rounds), sync, live


def run(args: argparse.Namespace, command_line: str) -> int:
    """Serve until SIGINT/SIGTERM.

    Parameters
    ----------
    args : argparse.Namespace
    command_line : str

    Returns
    -------
    int
        0 after a clean stop.
    """

    from ..network.brokers import EmbeddedBroker, parse_listen
    from ..network.fleetdir import load_aggregation, load_login, load_plan, load_trust
    from ..network.mqtt_client import MqttClient
    from ..network.mqtt_run import run_service
    from ..network.pgstore import open_service_store
    from ..network.tls import has_tls

    if args.map is not None and args.roads is None:
        from ..errors import ParameterError

        raise ParameterError("--map: needs --roads URL (the live map shows the road store)")
    map_at = parse_listen(args.map, "--map") if args.map is not None else None
    plan, trust, policy = load_plan(args.fleet), load_trust(args.fleet), load_aggregation(args.fleet)
    login = load_login(Path(args.fleet) / "service" / "broker.toml")
    store = open_service_store(args.store, plan)

    from ._service_status import ServiceStatus

    status = ServiceStatus(policy.secure)
    try:
        service, sync, live = _service(args, store, trust, policy, plan, command_line, map_at, status)
    except BaseException:
        status.stop()
        raise
    broker = None
    if args.broker is None:
        host, port = parse_listen(args.listen)
        broker = EmbeddedBroker(Path(args.fleet), host, port).start()
        url = f"{'mqtts' if has_tls(args.fleet) else 'mqtt'}://{host}:{port}"
    else:
        url = args.broker
    stop, republish = threading.Event(), threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    client = MqttClient(url, login, f"rc-service-{plan.fleet_id}" + (f"-{os.getpid()}" if args.shared else ""), on_connect=republish.set)
    private = {service.rounds.subscription} if service.rounds is not None else set()
    for filt in service.subscriptions:     # every service sees every round message; each answers its own rounds
        client.subscribe(f"$share/{plan.fleet_id}/{filt}" if args.shared and filt not in private else filt)
    try:
        client.connect()
        st = store.status()
        how = (f"; secure aggregation, rounds of {policy.round_size} (k={policy.min_inputs}, t={policy.threshold})"
               if policy.secure else "")
        if policy.validated:
            how = (f"; validated aggregation with the helpers {list(service.rounds.params.helper_ids)}, sessions of "
                   f"{policy.round_size} (k={policy.min_inputs}, {service.rounds.params.phases} phases)")
        print(f"serving fleet {plan.fleet_id!r} on {url}: store {args.store} holds {st['contributions']} "
              f"contributions from {st['vehicles']} vehicles{how}", flush=True)
        handled = run_service(service, client, stop, republish)
    finally:
        status.stop()
        client.close()
        if live is not None:
            live.stop()
        if broker is not None:
            broker.stop()
        if sync is not None:
            try:
                sync.flush()
                print(f"road store {args.roads}: {sync.written_segments} segment estimates and "
                      f"{sync.written_anomalies} anomalies written this run", flush=True)
            finally:
                sync.roads.close()
        store.close()
    print(f"stopped: {handled} messages handled this run, store {args.store} closed", flush=True)
    return 0
