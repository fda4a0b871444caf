"""A vehicle's side of validated, phased sessions (:mod:`.prioround`), and the in-memory driver.

:class:`PrioAgent` answers the leader's invites: phase 1 records the measurement in the vehicle's
:class:`~roadcollab.privacy.secagg_store.SessionLedger` (one session per (segment, epoch), across
restarts) and proves its input clipped into the wide box; phase ``k > 1`` first checks every aggregator's
signature on the previous result and records phase 1's set (a later phase over another set gets
nothing), then proves its deviation from the result scaled onto the public ball. Each helper's share is
sealed to that helper's advertised X25519 key (the leader relays it unread). :func:`run_prio_session`
runs one session over a :class:`~roadcollab.network.transport.MemoryBroker`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ..errors import MessageError, ParameterError
from ..privacy.secagg_messages import AggregationRefused, session_id
from ..privacy.secagg_phased import phase_session
from ..privacy.secagg_replicated import submit
from ..privacy.secagg_store import SessionLedger, segment_key
from ..wire.identity import FleetTrust, VehicleIdentity
from .aggregation import validated_input, validated_segments
from .messages import seal
from .prioround import PrioLeader, PrioParams, open_result
from .priowire import PrioTopics, commitments_blob, ids_field, int_field, open_advert, pack, share_blob, unpack
from .relaykey import seal_to
from .service import Publish
from .transport import MemoryBroker

__all__ = ["PrioAgent", "run_prio_session"]


class PrioAgent:
    """A vehicle in the validated sessions it is invited to.

    Parameters
    ----------
    identity : VehicleIdentity
    trust : FleetTrust
    params : PrioParams
    ledger : SessionLedger
        Persistent: one input per (segment, epoch); phase 1's set per session.
    prefix : str
    inputs : dict
        ``{(segment, epoch): u}`` or ``{segment: u}`` with ``u`` of ``params.wide.length`` values: what
        this vehicle measured.
    rng : numpy.random.Generator, optional
        Seeds and blinds (tests); default from the operating system's entropy.

    Attributes
    ----------
    refusals : list of str
        Why it sent nothing for an invite.
    closed : dict
        ``{(segment, epoch): outcome}``.
    """

    def __init__(self, identity: VehicleIdentity, trust: FleetTrust, params: PrioParams, ledger: SessionLedger,
                 prefix: str, inputs: dict, *, rng: np.random.Generator | None = None) -> None:
        self.identity, self.trust, self.params, self.ledger = identity, trust, params, ledger
        self.vid, self.prefix, self.inputs = identity.vehicle_id, prefix, dict(inputs)
        self.rng = np.random.default_rng() if rng is None else rng
        self._u: dict[tuple[int, int], np.ndarray] = {}
        self._answers: dict[tuple[int, int, int], list[Publish]] = {}
        self.refusals: list[str] = []
        self.closed: dict[tuple[int, int], str] = {}
        self.clipped = 0

    @property
    def subscription(self) -> str:
        return f"{self.prefix}/prio/+/+/to/{self.vid}"

    @staticmethod
    def round_input(plan, c):
        """Its input to the session of ``c.segment``, None unless it covered the segment whole
        (:func:`~roadcollab.network.aggregation.validated_input`).

        Parameters
        ----------
        plan : RoadPlan
        c : Contribution
        """
        return validated_input(plan, c)

    @staticmethod
    def hello_fields(engine) -> dict:
        """``{"validated": [...]}``: the segments it covered whole, so the service invites it to those only.

        Parameters
        ----------
        engine : VehicleEngine
        """
        return {"validated": validated_segments(engine)}

    def finished(self, segment: int) -> bool:
        """True when a session that took this vehicle's phase-1 upload on ``segment`` has closed (finished or
        aborted: the measurement is spent either way), or when its ledger says an earlier run of this vehicle
        spent it (a restart).

        Parameters
        ----------
        segment : int
        """
        if any(k[0] == segment and k in self._u for k in self.closed):
            return True
        return not any(k[0] == segment for k in self._u) and self.ledger.contributed(segment_key(segment))

    def on_message(self, topic: str, payload: bytes) -> list[Publish]:
        """React to one leader message; what to publish (refusals in :attr:`refusals`).

        Parameters
        ----------
        topic : str
        payload : bytes
        """
        try:
            s, e, rest = PrioTopics.parse(self.prefix, topic)
            if rest != ["to", self.vid]:
                return []
            h, blobs = unpack(payload, "leader message")
            if h.get("t") == "closed":
                self.closed.setdefault((s, e), str(h.get("outcome")))
                return []
            if h.get("t") != "invite":
                raise MessageError(f"unknown message {h.get('t')!r}")
            k = int_field(h, "phase", "invite", 1)
            if (s, e, k) in self._answers:          # an invite repeated: the same answer again
                return list(self._answers[(s, e, k)])
            out = self._answer((s, e), k, h, blobs)
            self._answers[(s, e, k)] = out
            return out
        except (MessageError, ParameterError) as err:
            self.refusals.append(f"{topic}: {err}")
            return []

    def _input(self, key: tuple[int, int]) -> np.ndarray:
        z = self.inputs.get(key, self.inputs.get(key[0]))
        if z is None:
            raise MessageError(f"invited to session {key} of a segment it has no measurement of")
        u = np.asarray(z, float).ravel()
        if u.size != self.params.wide.length or not np.all(np.isfinite(u)):
            raise ParameterError(f"the input of {key} must hold {self.params.wide.length} finite values")
        return u

    def _answer(self, key: tuple[int, int], k: int, h: dict, blobs: list[bytes]) -> list[Publish]:
        topics, session, p = PrioTopics(self.prefix, *key), session_id(*key), self.params
        if len(blobs) != len(p.aggregators) + 1:
            raise MessageError(f"invite: expected {len(p.aggregators)} key adverts and the previous result")
        certs, keys = {}, {}
        for party, advert in zip(p.aggregators, blobs):
            certs[party], keys[party] = open_advert(advert, self.trust, self.prefix, party)
        pid = int_field(h, "id", "invite", 1)
        enc = p.encoding(k)
        try:
            if k == 1:
                u, roster = self._input(key), ids_field(h, "roster", "invite")
                if key not in self.inputs:   # a measurement of the segment: one session in any epoch
                    self.ledger.record_contribution(segment_key(key[0]), roster)
                self.ledger.record_contribution(session, roster)
                self._u[key], _ = p.wide.clip(u)
                x = self._u[key]
            else:
                if key not in self._u:
                    raise MessageError(f"phase {k} of session {key} without its phase 1 here")
                acc, m = open_result(blobs[-1], self.trust, p, session, k - 1, certs)
                if pid not in acc:
                    raise MessageError(f"phase {k}: the previous result is not over this vehicle")
                if m.shape != self._u[key].shape or not np.all(np.isfinite(m)):
                    raise MessageError(f"phase {k}: the previous result has the wrong length or is not finite")
                self.ledger.record_view(session, acc)
                d, c = enc.onto_ball(self._u[key] - m)
                self.clipped += c
                x = np.clip(d, -enc.bounds, enc.bounds)
        except AggregationRefused as err:
            raise MessageError(f"sends nothing in phase {k}: {err}") from None
        up = submit(enc, x, phase_session(session, k), pid, self.rng, aggregators=len(p.aggregators),
                    identity=self.identity)
        f = enc.field
        sealed = [seal_to(keys[party], topics.sealed_part(pid, k, party), share_blob(sh, f))
                  for party, sh in zip(p.helper_ids, up.shares[1:])]
        body = pack({"t": "upload", "phase": k, "id": pid}, commitments_blob(up.commitments),
                    share_blob(up.shares[0], f), *sealed)
        topic = topics.up(self.vid)
        return [Publish(topic, seal(self.identity, topic, body))]


def run_prio_session(leader: PrioLeader, helpers, agents: dict, roster: list[str], *,
                     offline=(), timeouts: int = 3, limit: int = 1000) -> MemoryBroker:
    """One session over a fresh :class:`~roadcollab.network.transport.MemoryBroker`, to its end.

    Parameters
    ----------
    leader : PrioLeader
    helpers : PrioHelperService or list of them
        One per helper of ``leader.params``.
    agents : dict of str to PrioAgent
        Vehicles that answer (others of ``roster`` never do).
    roster : list of str
    offline : iterable of str
        Vehicles gone: they receive nothing.
    timeouts : int
        Leader timeouts at most (each closes the current phase's uploads, then gives up).
    limit : int
        Delivery passes at most per timeout.

    Returns
    -------
    MemoryBroker
        Its ``bytes_published``.
    """
    broker = MemoryBroker()
    a = broker.client()
    a.subscribe(f"{leader.topics.base}/up/+")
    for party in leader.params.helper_ids:
        a.subscribe(leader.topics.agg(party))
    parties: list[tuple[Any, Callable[[str, bytes], list[Publish]]]] = [(a, leader.handle)]
    for helper in (helpers if isinstance(helpers, (list, tuple)) else [helpers]):
        c = broker.client()
        for filt in helper.subscriptions:
            c.subscribe(filt)
        parties.append((c, helper.handle))
    clients = {v: broker.client() for v in agents}
    for v, c in clients.items():
        c.subscribe(agents[v].subscription)
    parties += [(c, (lambda t, p: []) if v in set(offline) else agents[v].on_message) for v, c in clients.items()]
    for p in leader.open(list(roster)):
        a.publish(p.topic, p.payload)
    for _ in range(timeouts + 1):
        for _ in range(limit):
            moved = 0
            for client, fn in parties:
                while (m := client.receive(0.0)) is not None:
                    moved += 1
                    for p in fn(*m):
                        client.publish(p.topic, p.payload, p.retain)
            if not moved:
                break
        else:
            raise ParameterError(f"the session did not settle within {limit} passes")
        if leader.done:
            break
        for p in leader.advance():
            a.publish(p.topic, p.payload)
    return broker
