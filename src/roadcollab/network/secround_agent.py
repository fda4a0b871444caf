"""A vehicle's side of :mod:`roadcollab.network.secround`'s rounds, and the in-memory drivers.

:class:`RoundAgent` answers the service's ``invite``, ``roster``, ``dealt``, ``survivors`` and
``signatures`` with one :class:`~roadcollab.privacy.secagg_active.SecAggVehicle` per round; its
:class:`~roadcollab.privacy.secagg_store.SessionLedger` (a file in its fleet folder) refuses a second
input for a (segment, epoch) across restarts. :func:`pump` and :func:`run_round` move messages over a
:class:`~roadcollab.network.transport.MemoryBroker`.
"""

from __future__ import annotations

import json

import numpy as np

from ..errors import MessageError, ParameterError
from ..privacy.secagg_active import SecAggVehicle
from ..privacy.secagg_messages import AggregationRefused, SecAggSpec, session_id
from ..privacy.secagg_store import SessionLedger, segment_key
from ..wire.identity import FleetTrust, VehicleIdentity
from ..wire.protocol import encode
from .aggregation import segment_input
from .messages import seal
from .secround import RoundCoordinator, RoundTopics, _b64, _int_map, _json
from .service import Publish
from .transport import MemoryBroker

__all__ = ["RoundAgent", "pump", "run_round", "clip_mean"]


class RoundAgent:
    """A vehicle's side of the rounds it is invited to: one :class:`SecAggVehicle` per round.

    Parameters
    ----------
    identity : VehicleIdentity
    trust : FleetTrust
    spec : SecAggSpec
    ledger : SessionLedger
        Persistent (its fleet folder): one input per (segment, epoch), one signed survivor set per session.
    fleet_id : str
        The topic prefix (``rc/{fleet_id}`` on the network).
    inputs : dict
        ``{(segment, epoch): z}`` or ``{segment: z}`` (any epoch) with ``z`` of shape (L, 2), m/s: what
        this vehicle measured. A measurement of a segment is given to at most one round: once its masked
        input was sent in round ``(segment, e)``, invites to ``(segment, e')`` are refused (differencing two
        rounds would otherwise isolate it), also after a restart: the ledger records the segment itself
        (:func:`~roadcollab.privacy.secagg_store.segment_key`), so every other epoch, earlier or later, is refused.
    root : callable, optional
        ``root(segment, epoch) -> 32 bytes`` of session secrets (tests); default :func:`os.urandom`.

    Attributes
    ----------
    refusals : list of str
        Why it stopped in a round (nothing was sent for that step).
    closed : dict
        ``{(segment, epoch): (outcome, used)}`` from the service's ``closed`` notices; ``used`` is
        True when this vehicle's masked input was part of the round.
    """

    def __init__(self, identity: VehicleIdentity, trust: FleetTrust, spec: SecAggSpec, ledger: SessionLedger,
                 fleet_id: str, inputs: dict, *, root=None) -> None:
        self.identity, self.trust, self.spec, self.ledger = identity, trust, spec, ledger
        self.vid, self.fleet_id, self.inputs, self._root = identity.vehicle_id, fleet_id, dict(inputs), root
        self.rounds: dict[tuple[int, int], SecAggVehicle] = {}
        self.dealt: dict[tuple[int, int], tuple[dict, dict]] = {}
        self.refusals: list[str] = []
        self.closed: dict[tuple[int, int], tuple[str, bool]] = {}
        self._spent: set[int] = set()
        self._spent_checked: set[int] = set()
        self._answers: dict[tuple[tuple[int, int], str], list[Publish]] = {}
        self.bytes_out = 0

    def _input(self, key: tuple[int, int]):
        if key in self.inputs:
            return self.inputs[key]
        s, e = key
        if s not in self.inputs:
            return None
        for k in self.rounds:   # another epoch of this segment already got the masked input
            if k[0] == s and k != key and (k in self.dealt or self.ledger.contributed(session_id(*k))):
                raise MessageError(f"invited to round {key}: its measurement of segment {s} went to round {k}")
        for e2 in range(min(e, 10000)):
            if self.ledger.contributed(session_id(s, e2)):
                raise MessageError(f"invited to round {key}: its measurement of segment {s} went to epoch {e2}")
        if self.ledger.contributed(segment_key(s)) and not self.ledger.contributed(session_id(s, e)):
            # any other epoch, earlier ones included, also after a restart (the loop above sees earlier ones only)
            raise MessageError(f"invited to round {key}: its measurement of segment {s} went to another round")
        return self.inputs[s]

    @staticmethod
    def round_input(plan, c):
        """Its input to the round of ``c.segment``: :func:`~roadcollab.network.aggregation.segment_input`.

        Parameters
        ----------
        plan : RoadPlan
        c : Contribution
        """
        return segment_input(plan, c)

    @staticmethod
    def hello_fields(engine) -> dict:
        """Hello fields the rounds need (none).

        Parameters
        ----------
        engine : VehicleEngine
        """
        return {}

    def finished(self, segment: int) -> bool:
        """True when a round that took this vehicle's masked input on ``segment`` has closed, or when its
        ledger says an earlier run of this vehicle already gave it (a restart: that round went on
        without this process).

        Parameters
        ----------
        segment : int
        """
        if any(k[0] == segment and used for k, (_, used) in self.closed.items()):
            return True
        if segment not in self._spent_checked:
            self._spent_checked.add(segment)
            if not any(k[0] == segment for k in self.rounds) and (self.ledger.contributed(segment_key(segment)) or
                                                                   any(self.ledger.contributed(session_id(segment, e))
                                                                       for e in range(64))):
                self._spent.add(segment)
        return segment in self._spent
    @property
    def subscription(self) -> str:
        """Topic filter of every round's messages to this vehicle."""
        return f"{self.fleet_id}/secagg/+/+/to/{self.vid}"

    def _send(self, key: tuple[int, int], kind: str, body: bytes) -> list[Publish]:
        topic = RoundTopics(self.fleet_id, *key).up(kind, self.vid)
        p = Publish(topic, seal(self.identity, topic, body))
        self.bytes_out += len(p.payload)
        return [p]

    def on_message(self, topic: str, payload: bytes) -> list[Publish]:
        """React to one service message; what to publish. Refusals go to :attr:`refusals`.

        Parameters
        ----------
        topic : str
        payload : bytes
        """
        try:
            s, e, rest = RoundTopics.parse_round(self.fleet_id, topic)
        except MessageError:
            return []
        if rest != ["to", self.vid]:
            return []
        try:
            key = (s, e)
            msg = _json(payload, "round message")
            return self._step(key, msg)
        except (MessageError, ParameterError, ValueError) as err:
            self.refusals.append(f"{topic}: {err}")
            return []

    def _step(self, key: tuple[int, int], msg: dict) -> list[Publish]:
        kind = str(msg.get("type"))
        if (key, kind) in self._answers:       # a request repeated (a restarted service): the first answer again
            return list(self._answers[(key, kind)])
        out = self._answer(key, kind, msg)
        if kind != "closed":
            self._answers[(key, kind)] = out
        return out

    def _answer(self, key: tuple[int, int], kind, msg: dict) -> list[Publish]:
        if kind == "closed":
            if key in self.rounds and key not in self.closed:
                used = msg.get("used")
                mine = isinstance(used, list) and self.rounds[key].vehicle in used and key in self.dealt
                self.closed[key] = (str(msg.get("outcome")), bool(mine))
            return []
        if kind == "invite":
            if self._input(key) is None:
                raise MessageError(f"invited to round {key} of a segment it has no measurement of")
            if key in self.rounds:
                raise MessageError(f"a second invite to round {key} (ignored)")
            pid = int(msg.get("id", 0))
            v = SecAggVehicle(pid, self.identity, self.trust, self.spec, self.ledger)
            self.rounds[key] = v
            root = None if self._root is None else self._root(*key)
            return self._send(key, "advert", v.advertise(session_id(*key), root=root))
        if key not in self.rounds:
            raise MessageError(f"{kind} for round {key} it was not invited to")
        v = self.rounds[key]
        if kind == "roster":
            sealed, com = v.share_keys(_int_map(msg.get("adverts"), "roster"))
            body = json.dumps({"sealed": {str(j): _b64(c) for j, c in sealed.items()}, "commitments": _b64(com)})
            return self._send(key, "shares", body.encode())
        if kind == "dealt":
            if key in self.dealt:
                raise MessageError(f"dealt shares of round {key} again (ignored)")
            self.dealt[key] = (_int_map(msg.get("sealed"), "dealt.sealed"),
                               _int_map(msg.get("commitments"), "dealt.commitments"))
            z = self._input(key)
            if key not in self.inputs:        # a measurement of the segment: spent for every epoch once sent
                try:
                    self.ledger.record_contribution(segment_key(key[0]), [v.vehicle])
                except AggregationRefused as err:
                    raise MessageError(f"round {key}: {err}") from None
            return self._send(key, "masked", encode(v.mask_input(z, key)))
        if kind == "survivors":
            ids = msg.get("ids")
            if not isinstance(ids, list) or not all(isinstance(i, int) for i in ids):
                raise MessageError("survivors: expected a list of protocol ids")
            return self._send(key, "sign", v.sign_survivors(ids))
        if kind == "signatures":
            sealed, coms = self.dealt[key]
            return self._send(key, "reveal", encode(v.reveal(sealed, coms, _int_map(msg.get("signatures"),
                                                                                  "signatures"))))
        raise MessageError(f"unknown round message type {kind!r}")


def pump(coordinator: RoundCoordinator, svc, agents: dict, clients: dict, *, limit: int = 1000,
         offline=()) -> int:
    """Deliver messages both ways over the transport until none move (``offline`` vehicles receive nothing).

    Parameters
    ----------
    coordinator : RoundCoordinator
    svc : Transport
        The service's client, subscribed to ``coordinator.topics.from_vehicles``.
    agents, clients : dict of str
        Vehicle id -> :class:`RoundAgent` / its transport client (subscribed to ``agent.subscription``).
    limit : int
        Most passes.
    offline : iterable of str
        Vehicles that are gone (a killed process): their queues are drained unread.

    Returns
    -------
    int
        Messages delivered.
    """
    gone, moved_total = set(offline), 0
    for _ in range(limit):
        moved = 0
        while (m := svc.receive(0.0)) is not None:
            for p in coordinator.handle(*m):
                svc.publish(p.topic, p.payload, p.retain)
            moved += 1
        for vid, car in clients.items():
            while (m := car.receive(0.0)) is not None:
                moved += 1
                if vid in gone:
                    continue
                for p in agents[vid].on_message(*m):
                    car.publish(p.topic, p.payload, p.retain)
        moved_total += moved
        if not moved:
            return moved_total
    raise ParameterError(f"the round did not settle within {limit} passes")


def run_round(coordinator: RoundCoordinator, agents: dict, roster: list, *, offline=(), timeouts: int = 6):
    """Open a round over a fresh :class:`~roadcollab.network.transport.MemoryBroker` and run it to its end.

    Parameters
    ----------
    coordinator : RoundCoordinator
    agents : dict of str to RoundAgent
        Vehicle id -> agent (vehicles of ``roster`` absent here never answer).
    roster : list of str
        Vehicles invited.
    offline : iterable of str
        Vehicles gone: they receive nothing.
    timeouts : int
        Service timeouts at most (each closes the current phase with what arrived).

    Returns
    -------
    MemoryBroker
        The transport (``bytes_published``).
    """
    broker = MemoryBroker()
    svc = broker.client()
    svc.subscribe(coordinator.topics.from_vehicles)
    clients = {}
    for vid, a in agents.items():
        clients[vid] = broker.client()
        clients[vid].subscribe(a.subscription)
    for p in coordinator.open(list(roster)):
        svc.publish(p.topic, p.payload)
    for _ in range(timeouts):
        pump(coordinator, svc, agents, clients, offline=offline)
        if coordinator.phase in ("finished", "aborted"):
            break
        for p in coordinator.advance():
            svc.publish(p.topic, p.payload)
    return broker


def clip_mean(zs, spec: SecAggSpec) -> np.ndarray:
    """The plain mean of the clipped inputs, m/s (what the round's revealed average must equal).

    Parameters
    ----------
    zs : iterable of (L, 2) array_like
        Inputs, m/s.
    spec : SecAggSpec
        Its ``clip``.

    Returns
    -------
    (L, 2) ndarray
    """
    return np.mean([np.clip(np.asarray(z, float), -spec.clip, spec.clip) for z in zs], axis=0)
