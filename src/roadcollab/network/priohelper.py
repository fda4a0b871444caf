"""Aggregator ``B`` of validated, phased sessions (:mod:`.prioround`): one process, every session.

:class:`PrioHelperService` routes the leader's messages to one :class:`PrioHelper` per measurement
``(segment, epoch)``. A helper trusts the leader for nothing but routing:

- it checks every vehicle's signature and certificate and its own share of every proof;
- it releases its sum share only over vehicles it accepted itself, at least ``k`` of them, once per
  (session, phase), and after phase 1 only over phase 1's set: all in its
  :class:`~roadcollab.privacy.secagg_store.ReleaseLog`, before the share is sent, so a restart does not
  release again (a restarted helper has lost its shares of a running session: that session aborts);
- it signs each phase's result ``m_k`` (session, phase, set): vehicles act on the leader's
  announcements only with that signature, so the leader cannot show vehicles different sets or results.
"""

from __future__ import annotations

import numpy as np

from ..errors import MessageError, ParameterError
from ..privacy.secagg_flp import Proof
from ..privacy.secagg_messages import AggregationRefused
from ..privacy.secagg_phased import phase_session
from ..privacy.secagg_store import ReleaseLog
from ..privacy.secagg_validity import HelperUpload, LeaderUpload, Submission
from ..wire.certificate import Certificate
from ..wire.identity import FleetTrust
from .messages import open_signed, seal
from .prioround import PrioAggregator, PrioParams
from .priowire import AggregatorKeys, PrioTopics, elements, ids_field, int_field, key_topic, open_advert, pack, \
    read_vshare, result_bytes, unpack, vshare_message
from .service import Publish

__all__ = ["PrioHelper", "PrioHelperService", "HelperParty"]


class PrioHelper(PrioAggregator):
    """Aggregator ``B`` of one session (module docstring).

    Parameters
    ----------
    prefix : str
    segment, epoch : int
    params : PrioParams
    trust : FleetTrust
    keys : AggregatorKeys
        ``B``'s identity (id ``params.helper_id``) and X25519 key.
    leader_advert : bytes
        ``A``'s signed key advert.
    log : ReleaseLog

    Attributes
    ----------
    events : list of (str, str)
        ``refused``, ``released``, ``closed``, ``excluded`` (a vehicle it accepted that the leader left out).
    """

    LEADER = False

    def __init__(self, prefix: str, segment: int, epoch: int, params: PrioParams, trust: FleetTrust,
                 keys: AggregatorKeys, leader_advert: bytes, log: ReleaseLog) -> None:
        super().__init__(prefix, segment, epoch, params, trust, keys, leader_advert, log)
        self.roster: dict[int, str] = {}
        self.closed = False

    def _send(self, header: dict, *blobs: bytes) -> list[Publish]:
        head = dict(header, phase=self.phase)
        return [Publish(self.topics.helper, seal(self.keys.identity, self.topics.helper, pack(head, *blobs)))]

    def handle(self, topic: str, payload: bytes) -> list[Publish]:
        """Apply one leader message; what to publish (refusals in :attr:`events`).

        Parameters
        ----------
        topic : str
        payload : bytes
        """
        if topic != self.topics.leader:
            return []
        try:
            _, body = open_signed(payload, self.trust, topic, self.params.leader_id)
            h, blobs = unpack(body, "leader message")
            return self._apply(h, blobs)
        except (MessageError, ParameterError) as err:
            self.events.append(("refused", f"{topic}: {err}"))
            return []

    def _apply(self, h: dict, blobs: list[bytes]) -> list[Publish]:
        kind = h.get("t")
        if self.closed:
            raise MessageError("the session is closed")
        if kind == "open":
            return self._open(h)
        if not self.roster:
            raise MessageError(f"{kind} before the session was opened")
        if kind == "closed":
            self.closed = True
            self.events.append(("closed", str(h.get("reason"))[:300]))
            return []
        if int_field(h, "phase", "leader message", 1) != self.phase:
            raise MessageError(f"a leader message of phase {h.get('phase')} in phase {self.phase}")
        if kind == "fwd":
            return self._forwarded(h, blobs)
        if kind == "vshare":
            share = read_vshare(h, blobs, self.params.encoding(self.phase).field)
            if share.vehicle not in self.roster or share.vehicle in self._peer:
                raise MessageError(f"a verifier share of vehicle {share.vehicle} that is not expected")
            self._peer[share.vehicle] = share
            self._decide_pair(share.vehicle)
            return []
        if kind == "accept":
            return self._release(ids_field(h, "accepted", "accept"), blobs)
        raise MessageError(f"unknown leader message {kind!r}")

    def _open(self, h: dict) -> list[Publish]:
        roster = h.get("roster")
        if self.roster or not isinstance(roster, dict) or not roster:
            raise MessageError("open: once, with a roster of vehicle ids to protocol ids")
        ids = {}
        for vid, i in roster.items():
            if isinstance(i, bool) or not isinstance(i, int) or i < 1 or i in ids:
                raise MessageError("open: protocol ids must be distinct positive integers")
            if str(vid) in (self.params.leader_id, self.params.helper_id):
                # An aggregator's certificate as a "vehicle": a Sybil whose input the leader knows.
                raise MessageError(f"open: the roster holds the aggregator id {vid!r}")
            ids[i] = str(vid)
        self.roster = ids
        return []

    def _forwarded(self, h: dict, blobs: list[bytes]) -> list[Publish]:
        i, k = int_field(h, "id", "fwd", 1), self.phase
        if i not in self.roster or i in self._own or i in self._decided or len(blobs) != 3:
            raise MessageError(f"a forwarded part of vehicle {i} that is not expected (or not 3 parts)")
        try:
            cert = Certificate.from_bytes(blobs[2])
            if cert.vehicle_id != self.roster[i]:
                raise MessageError(f"the certificate is {cert.vehicle_id}'s, not {self.roster[i]}'s")
            part = self.keys.key.open(self.topics.sealed_part(i, k), blobs[0])
            if len(part) != 64:
                raise MessageError("the sealed part must hold 64 bytes")
            empty = np.zeros(0, dtype=object)
            sub = Submission(i, LeaderUpload(empty, Proof(empty), b"", b""), HelperUpload(part[:16], part[16:32],
                                                                                         part[32:]), blobs[1])
            vb = self._agg.prepare(sub, phase_session(self.session, k), self.trust, cert)
        except MessageError as err:
            self._decided[i] = f"vehicle {i}: {err}"
            return self._send({"t": "reject", "id": i, "reason": str(err)[:300]})
        self._own[i] = vb
        self._decide_pair(i)
        return self._send(*vshare_message(vb, self.params.encoding(k).field))

    def _release(self, acc: tuple[int, ...], blobs: list[bytes]) -> list[Publish]:
        k, enc = self.phase, self.params.encoding(self.phase)
        mine = {i for i, why in self._decided.items() if not why}
        try:
            if not set(acc) <= mine:
                raise AggregationRefused(f"the leader's set holds vehicles {sorted(set(acc) - mine)} this aggregator "
                                         "did not accept")
            if len(blobs) != 1:
                raise MessageError("accept: expected the leader's sum share")
            share_a = elements(enc.field, blobs[0], "leader sum share", enc.length)
            self.log.release(self.session, k, acc)
            share = self._agg.aggregate_share(acc, self.params.min_inputs)
        except AggregationRefused as err:
            self.events.append(("refused", f"phase {k}: {err}"))
            return self._send({"t": "refuse", "reason": str(err)[:300]})
        if mine - set(acc):
            self.events.append(("excluded", f"phase {k}: the leader left out accepted vehicles {sorted(mine - set(acc))}"))
        m = self._next_m((share_a + share) % enc.field.p, len(acc))
        mb = m.astype("<f8").tobytes()
        sig = self.keys.identity.sign(result_bytes(self.session, k, acc, mb))
        out = self._send({"t": "result", "accepted": list(acc)}, enc.field.to_bytes(share), mb, sig)
        self.events.append(("released", f"phase {k} over {len(acc)} vehicles"))
        self._m = m
        if k < self.params.phases:
            self.phase += 1
            self._new_phase()
        return out


class PrioHelperService:
    """Aggregator ``B`` for every session of a fleet: routes the leader's messages by measurement.

    Parameters
    ----------
    prefix : str
    params : PrioParams
    trust : FleetTrust
    keys : AggregatorKeys
    leader_advert : bytes
    log : ReleaseLog
        Shared by every session (persisted).
    """

    def __init__(self, prefix: str, params: PrioParams, trust: FleetTrust, keys: AggregatorKeys,
                 leader_advert: bytes, log: ReleaseLog) -> None:
        self.prefix, self.params, self.trust, self.keys, self.log = prefix, params, trust, keys, log
        self.leader_advert = bytes(leader_advert)
        open_advert(self.leader_advert, trust, prefix, params.leader_id)        # fails early on a bad advert
        self.sessions: dict[tuple[int, int], PrioHelper] = {}

    @property
    def subscription(self) -> str:
        return f"{self.prefix}/prio/+/+/leader"

    def handle(self, topic: str, payload: bytes) -> list[Publish]:
        """Route one message to its session's helper (created on first sight; it refuses all but ``open``).

        Parameters
        ----------
        topic : str
        payload : bytes
        """
        try:
            s, e, rest = PrioTopics.parse(self.prefix, topic)
        except MessageError:
            return []
        if rest != ["leader"]:
            return []
        if (s, e) not in self.sessions:
            self.sessions[(s, e)] = PrioHelper(self.prefix, s, e, self.params, self.trust, self.keys,
                                               self.leader_advert, self.log)
        return self.sessions[(s, e)].handle(topic, payload)


class HelperParty:
    """The helper as a long-running party of a fleet (``roadcollab helper``): it advertises its key, waits for
    the leader's signed advert (retained on its topic), then answers every session through a
    :class:`PrioHelperService`. Has the service's loop interface (``on_connect``, ``tick``, ``handle``,
    :func:`~roadcollab.network.mqtt_run.run_service`).

    Parameters
    ----------
    prefix : str
    params : PrioParams
    trust : FleetTrust
    keys : AggregatorKeys
        ``B``'s identity and X25519 key.
    log : ReleaseLog
    on_event : callable, optional
        One line per event (the leader's advert, a session closed, a refusal).
    """

    def __init__(self, prefix: str, params: PrioParams, trust: FleetTrust, keys: AggregatorKeys, log: ReleaseLog,
                 on_event=None) -> None:
        self.prefix, self.params, self.trust, self.keys, self.log = prefix, params, trust, keys, log
        self.service: PrioHelperService | None = None
        self._event = on_event or (lambda line: None)
        self._closed: set[tuple[int, int]] = set()

    @property
    def subscriptions(self) -> list[str]:
        return [key_topic(self.prefix, self.params.leader_id), f"{self.prefix}/prio/+/+/leader"]

    def on_connect(self) -> list[Publish]:
        """Its key advert, retained (again after every connection)."""
        return [Publish(key_topic(self.prefix, self.keys.party), self.keys.advert(self.prefix), retain=True)]

    def tick(self) -> list[Publish]:
        return []

    def handle(self, topic: str, payload: bytes) -> list[Publish]:
        """The leader's advert, or a leader message of a session; what to publish (nothing raises).

        Parameters
        ----------
        topic : str
        payload : bytes
        """
        if topic == key_topic(self.prefix, self.params.leader_id):
            try:
                svc = PrioHelperService(self.prefix, self.params, self.trust, self.keys, bytes(payload), self.log)
            except (MessageError, ParameterError) as err:
                self._event(f"refused the leader's key advert: {err}")
                return []
            if self.service is None or svc.leader_advert != self.service.leader_advert:
                self.service = svc       # a new leader key: sessions from now on are checked against it
                self._event("the leader's key advert arrived")
            return []
        if self.service is None:
            return []
        out = self.service.handle(topic, payload)
        try:               # only this message's session can have closed
            key = PrioTopics.parse(self.prefix, topic)[:2]
        except MessageError:
            return out
        h = self.service.sessions.get(key)
        if h is not None and h.closed and key not in self._closed:
            self._closed.add(key)
            self._event(f"session {key[0]}/{key[1]}: closed")
        return out
