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

import time
from collections import OrderedDict
from typing import Callable

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

#: Events a session keeps (the first ones; a deviating leader can send any number of refused messages).
MAX_EVENTS = 200


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
        self.finished = False

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
            self.events.append(("refused", f"{topic}: {str(err)[:300]}"))
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
            self.closed = self.finished = True
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
        else:
            self.finished = True          # the last phase is released: nothing is left to answer
        return out

    def forget(self) -> None:
        """Drop the session's per-vehicle state (uploads, verifier shares, the sum share): a finished session
        keeps its roster, its events and :attr:`closed` only (:class:`PrioHelperService` calls it)."""
        self._new_phase()
        self._m = None
        self.roster = {}
        del self.events[MAX_EVENTS:]


class PrioHelperService:
    """Aggregator ``B`` for every session of a fleet: routes the leader's messages by measurement.

    A long-running helper keeps only what it still needs: a session that finished (its last phase
    released, or closed by the leader) or that heard no valid leader message for ``max_idle_s`` leaves the
    open sessions, its per-vehicle state and roster are dropped (:meth:`PrioHelper.forget`), and its key
    and first :data:`MAX_EVENTS` events are kept among the last ``max_finished`` finished sessions; a
    later message for it is dropped. A session is created only for a message signed by the leader on its
    session's own topic. Whatever is forgotten, the persisted
    :class:`~roadcollab.privacy.secagg_store.ReleaseLog` still refuses a second release of any (session,
    phase).

    How many sessions are open at once is the leader's to decide (one per segment with vehicles): by
    default the helper refuses none, since a session it drops aborts and spends its vehicles'
    measurement. ``max_open`` caps them for an operator who prefers that to the memory (about 10 MB per
    open session at L = 4,000 with 4 vehicles).

    Parameters
    ----------
    prefix : str
    params : PrioParams
    trust : FleetTrust
    keys : AggregatorKeys
    leader_advert : bytes
    log : ReleaseLog
        Shared by every session (persisted).
    max_open : int, optional
        Sessions open at once (default: no limit).
    max_idle_s : float
        Seconds without a valid leader message after which :meth:`expire` ends an open session; the
        default is twice ``serve``'s longest round timeout (3,600 s), so a phase waiting for slow vehicles
        is never ended.
    max_finished : int
        Finished sessions remembered.
    clock : callable
        Seconds (``time.monotonic``).

    Attributes
    ----------
    sessions : dict
        The open sessions' :class:`PrioHelper` by ``(segment, epoch)``.
    finished : OrderedDict
        ``(segment, epoch) -> (why, PrioHelper)`` of the finished ones, oldest first; ``why`` is
        ``"finished"`` or ``"idle"``.
    refused : list of str
        Sessions refused because ``max_open`` were open (the first 1,000).
    """

    def __init__(self, prefix: str, params: PrioParams, trust: FleetTrust, keys: AggregatorKeys,
                 leader_advert: bytes, log: ReleaseLog, *, max_open: int | None = None, max_idle_s: float = 7200.0,
                 max_finished: int = 65536, clock: Callable[[], float] = time.monotonic) -> None:
        self.prefix, self.params, self.trust, self.keys, self.log = prefix, params, trust, keys, log
        self.leader_advert = bytes(leader_advert)
        open_advert(self.leader_advert, trust, prefix, params.leader_id)        # fails early on a bad advert
        self.max_open, self.max_idle_s, self.max_finished = max_open, float(max_idle_s), max_finished
        self._clock = clock
        self.sessions: dict[tuple[int, int], PrioHelper] = {}
        self._heard: dict[tuple[int, int], float] = {}
        self.finished: OrderedDict[tuple[int, int], tuple[str, PrioHelper]] = OrderedDict()
        self.refused: list[str] = []

    @property
    def subscription(self) -> str:
        return f"{self.prefix}/prio/+/+/leader"

    def session(self, key: tuple[int, int]) -> PrioHelper | None:
        """The open or finished session ``(segment, epoch)`` (None if unknown or forgotten).

        Parameters
        ----------
        key : (int, int)
        """
        if key in self.sessions:
            return self.sessions[key]
        return self.finished[key][1] if key in self.finished else None

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
        key = (s, e)
        if rest != ["leader"] or key in self.finished:
            return []
        h = self.sessions.get(key)
        if h is None:
            try:     # only the leader's own signed message on the canonical topic opens a session here
                if topic != PrioTopics(self.prefix, s, e).leader:
                    return []
                open_signed(payload, self.trust, topic, self.params.leader_id)
            except (MessageError, ParameterError):
                return []
            if self.max_open is not None and len(self.sessions) >= self.max_open:
                if len(self.refused) < 1000:       # the first ones tell the operator enough
                    self.refused.append(f"session {s}/{e} refused: {self.max_open} sessions are open")
                return []
            h = self.sessions[key] = PrioHelper(self.prefix, s, e, self.params, self.trust, self.keys,
                                                self.leader_advert, self.log)
            self._heard[key] = self._clock()
        before = len(h.events)
        out = h.handle(topic, payload)
        if not any(kind == "refused" for kind, _ in h.events[before:]):
            self._heard[key] = self._clock()          # a refused message keeps no session alive
        del h.events[MAX_EVENTS:]
        if h.finished:
            self._finish(key, "finished")
        return out

    def expire(self) -> list[tuple[int, int]]:
        """End the open sessions that heard nothing for ``max_idle_s`` (a leader that went away).

        Returns
        -------
        list of (int, int)
            Their keys.
        """
        now = self._clock()
        stale = [key for key, t in self._heard.items() if now - t > self.max_idle_s]
        for key in stale:
            self._finish(key, "idle")
        return stale

    def _finish(self, key: tuple[int, int], why: str) -> None:
        h = self.sessions.pop(key)
        self._heard.pop(key, None)
        h.forget()
        self.finished[key] = (why, h)
        while len(self.finished) > self.max_finished:
            self.finished.popitem(last=False)


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

    @property
    def subscriptions(self) -> list[str]:
        return [key_topic(self.prefix, self.params.leader_id), f"{self.prefix}/prio/+/+/leader"]

    def on_connect(self) -> list[Publish]:
        """Its key advert, retained (again after every connection)."""
        return [Publish(key_topic(self.prefix, self.keys.party), self.keys.advert(self.prefix), retain=True)]

    def tick(self) -> list[Publish]:
        """Ends the sessions idle for too long (:meth:`PrioHelperService.expire`); publishes nothing."""
        if self.service is not None:
            for s, e in self.service.expire():
                self._event(f"session {s}/{e}: no message for {self.service.max_idle_s:.0f} s, ended")
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
        try:
            key = PrioTopics.parse(self.prefix, topic)[:2]
        except MessageError:
            return []
        known, refused = key in self.service.finished, len(self.service.refused)
        out = self.service.handle(topic, payload)
        if not known and key in self.service.finished:
            self._event(f"session {key[0]}/{key[1]}: finished")
        if len(self.service.refused) > refused:
            self._event(self.service.refused[-1])
        return out
