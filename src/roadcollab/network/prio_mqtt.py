"""Validated, phased sessions (:mod:`.prioround`) with every party its own process over an MQTT broker.

``python -m roadcollab.network.prio_mqtt ROLE --folder DIR --broker URL --params FILE --segment S --epoch E``
with ``ROLE`` one of ``leader`` (``--roster v1,v2,..``), ``helper`` or ``vehicle``. Each party connects with
its own login; the aggregators advertise their X25519 keys as retained messages signed by their
identities; the leader reads the helpers' adverts from the broker (:func:`~.priowire.open_advert`) and
the vehicles get every aggregator's advert with each invite. The process ends when the session closes (or after
``--timeout`` seconds: return code 3).

A party's folder holds ``certificate.bin`` and ``identity.key`` (:class:`~roadcollab.wire.identity.VehicleIdentity`),
``trust.toml``, ``broker.toml`` (its login), ``x25519.key`` (aggregators, :class:`~.relaykey.RelayKey`) or
``input.npy`` (a vehicle's measurement, ``L`` values), and gets what the party keeps: ``ledger.sqlite``
(vehicle), ``releases.sqlite`` (aggregators), ``result.json`` (leader; an existing one is never replaced).
The parameters file is :func:`params_to_dict`'s JSON, the same for every party.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, MessageError, ParameterError
from ..privacy.secagg_flp import ValidityEncoding
from ..privacy.secagg_store import ReleaseLog, SessionLedger
from ..wire.identity import FleetTrust, VehicleIdentity
from .fleetdir import load_login
from .mqtt_client import MqttClient
from .mqtt_run import _guarded
from .prioagent import PrioAgent
from .priohelper import PrioHelperService
from .prioround import PrioLeader, PrioParams
from .priowire import AggregatorKeys, key_topic
from .relaykey import RelayKey
from .service import Publish

__all__ = ["params_to_dict", "params_from_dict", "main"]


def _encoding_dict(e: ValidityEncoding) -> dict:
    return {"bounds": [float(b) for b in e.bounds], "resolution": float(e.resolution), "norm": float(e.norm)}


def params_to_dict(params: PrioParams, prefix: str) -> dict:
    """The public parameters as JSON-ready values (every party loads the same file).

    Parameters
    ----------
    params : PrioParams
    prefix : str
        Topic prefix (``rc/{fleet_id}``).
    """
    return {"prefix": prefix, "wide": _encoding_dict(params.wide), "tight": [_encoding_dict(e) for e in params.tight],
            "min_inputs": params.min_inputs, "leader_id": params.leader_id, "helper_ids": list(params.helper_ids)}


def params_from_dict(d: dict, where: str) -> tuple[PrioParams, str]:
    """``(PrioParams, prefix)`` of :func:`params_to_dict`'s form; ParameterError naming ``where``.

    Parameters
    ----------
    d : dict
    where : str
        The file it was read from.
    """
    try:
        enc = [ValidityEncoding(np.asarray(e["bounds"], float), float(e["resolution"]), norm=float(e.get("norm", 0.0)))
               for e in [d["wide"], *d["tight"]]]
        helpers = d["helper_ids"]
        if not isinstance(helpers, list):
            raise TypeError("helper_ids must be a list")
        return (PrioParams(enc[0], tuple(enc[1:]), int(d["min_inputs"]), str(d["leader_id"]),
                           tuple(str(h) for h in helpers)), str(d["prefix"]))
    except (KeyError, TypeError, ValueError) as err:
        raise ParameterError(f"{where}: not validated-session parameters ({err!r})") from None


def _loop(client: MqttClient, handle: Callable[[str, bytes], list[Publish]], done: Callable[[], bool],
          deadline: float, advance: Callable[[], list[Publish]] | None = None, idle: float = 5.0) -> bool:
    """Answer messages until ``done()`` (True) or the deadline (False); ``advance`` after ``idle`` quiet seconds."""
    last = time.monotonic()
    while not done():
        now = time.monotonic()
        if now > deadline:
            return False
        m = client.receive(0.2)
        if m is None:
            if advance is not None and now - last > idle:
                for p in advance():
                    client.publish(p.topic, p.payload, p.retain)
                last = time.monotonic()
            continue
        last = time.monotonic()
        for p in _guarded(functools.partial(handle, *m), f"a message on {m[0][:200]!r}", None):
            client.publish(p.topic, p.payload, p.retain)
    return True


def _advert(client: MqttClient, prefix: str, party: str, deadline: float) -> bytes:
    """Aggregator ``party``'s retained key advert (checked by the caller)."""
    topic = key_topic(prefix, party)
    client.subscribe(topic)
    while time.monotonic() < deadline:
        m = client.receive(0.2)
        if m is not None and m[0] == topic:
            return m[1]
    raise ParameterError(f"no key advert of {party!r} on {topic} before the timeout")


def _connect(folder: Path, url: str, client_id: str) -> MqttClient:
    return MqttClient(url, load_login(folder / "broker.toml"), client_id).connect()


def _write_result(path: Path, leader: PrioLeader) -> None:
    out = {"state": leader.state, "phase": leader.phase, "accepted": list(leader.accepted),
           "refused": {str(i): r for i, r in leader.refused.items()},
           "result": None if leader.result is None else [float(v) for v in leader.result],
           "events": [list(e) for e in leader.events]}
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    with os.fdopen(fd, "w") as fh:
        json.dump(out, fh, indent=1)


def _run(args: argparse.Namespace) -> int:
    folder = Path(args.folder)
    if args.role == "leader" and (folder / "result.json").exists():
        raise ParameterError(f"--folder {folder}: result.json exists (a session's result is never replaced)")
    params, prefix = params_from_dict(json.loads(Path(args.params).read_text()), args.params)
    trust, identity = FleetTrust.load(folder / "trust.toml"), VehicleIdentity.load(folder)
    deadline = time.monotonic() + args.timeout
    client = _connect(folder, args.broker, f"{prefix}-{args.role}-{identity.vehicle_id}".replace("/", "-"))
    try:
        if args.role == "vehicle":
            agent = PrioAgent(identity, trust, params, SessionLedger(folder / "ledger.sqlite"), prefix,
                              {(args.segment, args.epoch): np.load(folder / "input.npy")})
            client.subscribe(agent.subscription)
            ok = _loop(client, agent.on_message, lambda: (args.segment, args.epoch) in agent.closed, deadline)
            for r in agent.refusals:
                print(f"refused: {r}", file=sys.stderr)
            return 0 if ok else 3
        keys = AggregatorKeys(identity, RelayKey.load(folder / "x25519.key"))
        log = ReleaseLog(folder / "releases.sqlite")
        if args.role == "helper":
            svc = PrioHelperService(prefix, params, trust, keys, log)
            for filt in svc.subscriptions:      # before the advert: once the leader sees it, this helper listens
                client.subscribe(filt)
            client.publish(key_topic(prefix, keys.party), keys.advert(prefix), retain=True)
            key = (args.segment, args.epoch)
            ok = _loop(client, svc.handle, lambda: key in svc.finished, deadline)
            time.sleep(1.0)                   # its last messages (the result) leave before the client does
            return 0 if ok else 3
        client.publish(key_topic(prefix, keys.party), keys.advert(prefix), retain=True)
        leader = PrioLeader(prefix, args.segment, args.epoch, params, trust, keys,
                            [_advert(client, prefix, h, deadline) for h in params.helper_ids], log)
        client.subscribe(f"{leader.topics.base}/up/+")
        for h in params.helper_ids:
            client.subscribe(leader.topics.agg(h))
        time.sleep(args.settle)           # the others subscribe (their sessions are persistent after that)
        for p in leader.open(args.roster.split(",")):
            client.publish(p.topic, p.payload)
        ok = _loop(client, leader.handle, lambda: leader.done, deadline, leader.advance, args.idle)
        time.sleep(1.0)                   # the closing notices leave before the client does
        _write_result(folder / "result.json", leader)
        print(f"session {leader.state}: accepted {list(leader.accepted)}, refused {sorted(leader.refused)}")
        return 0 if ok else 3
    finally:
        client.close()


def main(argv: list[str] | None = None) -> int:
    """The process entry (module docstring); 0 when the session closed, 2 on bad input, 3 on timeout.

    Parameters
    ----------
    argv : list of str, optional
    """
    p = argparse.ArgumentParser(prog="python -m roadcollab.network.prio_mqtt")
    p.add_argument("role", choices=("leader", "helper", "vehicle"))
    p.add_argument("--folder", required=True)
    p.add_argument("--broker", required=True)
    p.add_argument("--params", required=True)
    p.add_argument("--segment", type=int, required=True)
    p.add_argument("--epoch", type=int, default=0)
    p.add_argument("--roster", default="")
    p.add_argument("--timeout", type=float, default=300.0)
    p.add_argument("--idle", type=float, default=10.0, help="leader: close a phase after this many quiet seconds")
    p.add_argument("--settle", type=float, default=2.0, help="leader: seconds before inviting")
    args = p.parse_args(argv)
    try:
        return _run(args)
    except (ParameterError, FileFormatError, MessageError, OSError, ValueError) as err:
        print(f"prio_mqtt {args.role}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
