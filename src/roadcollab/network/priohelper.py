"""The helpers ``B`` and ``C`` of validated, phased sessions (:mod:`.prioround`): one process, every session.

:class:`PrioHelperService` routes the aggregators' messages to one :class:`PrioHelper` per measurement
``(segment, epoch)``. A helper trusts the leader for nothing but routing:

- it opens its own share of every vehicle's upload (sealed to it; the leader relays it unread) and checks
  it against the vehicle's signed commitments;
- it takes part in the coin toss of the proofs' query randomness, so no party (the leader included) can
  tell a vehicle the randomness before the uploads close;
- it decides every vehicle from all aggregators' verifier shares, and releases its components' sums only
  once every aggregator announced the same accepted set of at least ``k`` vehicles, once per (session,
  phase), after phase 1 only over phase 1's set: all in its
  :class:`~roadcollab.privacy.secagg_store.ReleaseLog`, before the sums are sent, so a restart does not
  release again (a restarted helper has lost its shares of a running session: that session aborts);
- it signs a phase's result ``m_k`` only if the two holders of every component reported the same sum:
  vehicles act on a result only with every aggregator's signature.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from typing import Callable

import numpy as np

from ..errors import MessageError, ParameterError
from ..privacy.secagg_store import ReleaseLog
from ..wire.certificate import Certificate
from ..wire.identity import FleetTrust
from .messages import open_signed
from .prioaggregator import PrioAggregator
from .prioparams import MAX_EVENTS, PrioParams
from .priowire import MAX_ID, AggregatorKeys, PrioTopics, int_field, key_topic, unpack
from .service import Publish

__all__ = ["PrioHelper", "PrioHelperService", "HelperParty"]

#: Leader messages a helper keeps for a session it has not been told the roster of yet: how many, and their
#: bytes (a message may be up to ``MAX_MESSAGE_BYTES``, tens of MB: a count alone bounds no memory).
MAX_EARLY, MAX_EARLY_BYTES = 4096, 64 << 20
#: Another helper's messages kept for sessions the leader has not opened yet: per session, sessions, and
#: their bytes in all (the oldest session's are dropped first).
MAX_EARLY_PEER, MAX_EARLY_SESSIONS, MAX_EARLY_PEER_BYTES = 16, 1024, 64 << 20


class PrioHelper(PrioAggregator):
    """A helper of one session (module docstring).

    Parameters
    ----------
    prefix : str
    segment, epoch : int
    params : PrioParams
    trust : FleetTrust
    keys : AggregatorKeys
        The helper's identity (one of ``params.helper_ids``) and X25519 key.
    log : ReleaseLog
    rng : numpy.random.Generator, optional
        Its coins (tests).

    Attributes
    ----------
    events : list of (str, str)
        ``refused``, ``duplicate``, ``released``, ``closed``, ``aborted``, ``finished``.
    closed : bool
        The leader closed the session (or it aborted here).
    """

    def __init__(self, prefix: str, segment: int, epoch: int, params: PrioParams, trust: FleetTrust,
                 keys: AggregatorKeys, log: ReleaseLog, rng: np.random.Generator | None = None) -> None:
        if keys.party not in params.helper_ids:
            raise ParameterError(f"the helper's identity is {keys.party!r}, expected one of {list(params.helper_ids)}")
        super().__init__(prefix, segment, epoch, params, trust, keys, log, rng)
        self.closed = False
        self._early: list[tuple[str, bytes]] = []

    def handle(self, topic: str, payload: bytes) -> list[Publish]:
        """Apply one aggregator message; what to publish (refusals in :attr:`events`).

        Parameters
        ----------
        topic : str
        payload : bytes
        """
        rest = topic[len(self.topics.base) + 1:].split("/") if topic.startswith(self.topics.base + "/") else []
        try:
            if self.closed:
                raise MessageError("the session is closed")
            if rest == ["fwd", self.party]:
                return self._forwarded(topic, payload)
            if len(rest) == 2 and rest[0] == "agg" and rest[1] in self.params.aggregators and rest[1] != self.party:
                out = self._from_aggregator(rest[1], topic, payload)
                if self.aborted:
                    self.closed = True
                return out
            return []
        except (MessageError, ParameterError) as err:
            self.events.append(("refused", f"{topic}: {str(err)[:300]}"))
            del self.events[MAX_EVENTS:]
            return []

    def _abort(self, reason: str) -> list[Publish]:
        out = super()._abort(reason)
        self.closed = True
        return out

    def _on_open(self, party: str, h: dict) -> None:
        roster = h.get("roster")
        if party != self.params.leader_id or self.roster or not isinstance(roster, dict) or not roster:
            raise MessageError("open: once, by the leader, with a roster of vehicle ids to protocol ids")
        ids = {}
        for vid, i in roster.items():
            if isinstance(i, bool) or not isinstance(i, int) or not 0 < i < MAX_ID or i in ids:
                raise MessageError(f"open: protocol ids must be distinct integers from 1 to {MAX_ID - 1}")
            if str(vid) in self.params.aggregators:
                # An aggregator's certificate as a "vehicle": a Sybil whose input the leader knows.
                raise MessageError(f"open: the roster holds the aggregator id {vid!r}")
            ids[i] = str(vid)
        self.roster = ids

    def _on_closed(self, party: str, h: dict) -> list[Publish]:
        if party != self.params.leader_id:
            raise MessageError("closed is the leader's")
        self.closed = True
        if not self.finished:
            self.aborted = True
        self.events.append(("closed", str(h.get("reason"))[:300]))
        return []

    def _on_peer_abort(self) -> list[Publish]:
        self.closed = True
        return []

    def _progress(self) -> list[Publish]:
        out = []
        if self.roster and self._early:      # uploads the leader forwarded before this helper saw its open
            early, self._early = self._early, []
            for topic, payload in early:
                out += self._forwarded(topic, payload)
        return out + super()._progress()

    def _forwarded(self, topic: str, payload: bytes) -> list[Publish]:
        _, body = open_signed(payload, self.trust, topic, self.params.leader_id)
        h, blobs = unpack(body, "forwarded upload")
        if not self.roster:
            if len(self._early) >= MAX_EARLY or \
                    sum(len(p) for _, p in self._early) + len(payload) > MAX_EARLY_BYTES:
                raise MessageError("too many forwarded uploads (or bytes) before the session was opened")
            self._early.append((topic, payload))
            return []
        i, k = int_field(h, "id", "fwd", 1), int_field(h, "phase", "fwd", 1)
        ph = self._phases.get(k)
        if ph is None or k != self.phase or h.get("t") != "fwd" or len(blobs) != 3:
            raise MessageError(f"a forwarded upload of phase {k} in phase {self.phase} (or not 3 parts)")
        if i not in self._expected() or i in ph.agg.held or i in ph.rejected or ph.closed is not None \
                and i not in ph.closed:
            raise MessageError(f"a forwarded upload of vehicle {i} that is not expected")
        try:
            cert = Certificate.from_bytes(blobs[2])
            share = self.keys.key.open(self.topics.sealed_part(i, k, self.party), blobs[0])
        except MessageError as err:
            ph.rejected[i] = f"vehicle {i}: {err}"[:300]
            return self._progress()
        self._receive(i, cert, blobs[1], share, k)
        return self._progress()

    def forget(self) -> None:
        """Drop the session's per-vehicle state (uploads, verifier shares, sums): a finished session keeps its
        roster ids, its events and :attr:`closed` only (:class:`PrioHelperService` calls it)."""
        self._phases = {}
        self._early = []
        self._m = None
        self.roster = {}
        del self.events[MAX_EVENTS:]


class PrioHelperService:
    """A helper for every session of a fleet: routes the aggregators' messages by measurement.

    A long-running helper keeps only what it still needs: a session that finished (its last phase
    released, or closed by the leader) or that heard no valid aggregator message for ``max_idle_s`` leaves
    the open sessions, its per-vehicle state and roster are dropped (:meth:`PrioHelper.forget`), and its key
    and first :data:`MAX_EVENTS` events are kept among the last ``max_finished`` finished sessions; a
    later message for it is dropped. A session is created only for a message the leader signed on its own
    topic of that session; the other helper's messages that arrive first (its commitment may) are kept,
    a few per session, until then. Whatever is forgotten, the persisted
    :class:`~roadcollab.privacy.secagg_store.ReleaseLog` still refuses a second coin toss or release of any
    (session, phase).

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
        This helper's identity (one of ``params.helper_ids``) and X25519 key.
    log : ReleaseLog
        Shared by every session (persisted).
    max_open : int, optional
        Sessions open at once (default: no limit).
    max_idle_s : float
        Seconds without a valid aggregator message after which :meth:`expire` ends an open session; the
        default is twice ``serve``'s longest round timeout (3,600 s), so a phase waiting for slow vehicles
        is never ended.
    max_finished : int
        Finished sessions remembered.
    clock : callable
        Seconds (``time.monotonic``).
    rng : numpy.random.Generator, optional
        Coins (tests); default the operating system's entropy.

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

    def __init__(self, prefix: str, params: PrioParams, trust: FleetTrust, keys: AggregatorKeys, log: ReleaseLog, *,
                 max_open: int | None = None, max_idle_s: float = 7200.0, max_finished: int = 65536,
                 clock: Callable[[], float] = time.monotonic, rng: np.random.Generator | None = None) -> None:
        if keys.party not in params.helper_ids:
            raise ParameterError(f"the helper's identity is {keys.party!r}, expected one of {list(params.helper_ids)}")
        self.prefix, self.params, self.trust, self.keys, self.log = prefix, params, trust, keys, log
        self.max_open, self.max_idle_s, self.max_finished = max_open, float(max_idle_s), max_finished
        self._clock, self._rng = clock, rng
        self.sessions: dict[tuple[int, int], PrioHelper] = {}
        self._heard: dict[tuple[int, int], float] = {}
        self.finished: OrderedDict[tuple[int, int], tuple[str, PrioHelper]] = OrderedDict()
        self.refused: list[str] = []
        self._early: OrderedDict[tuple[int, int], list[tuple[str, bytes]]] = OrderedDict()
        self._early_bytes = 0

    @property
    def subscriptions(self) -> list[str]:
        """The other aggregators' session topics and this helper's forwarded uploads."""
        return [f"{self.prefix}/prio/+/+/agg/{p}" for p in self.params.aggregators if p != self.keys.party] + \
            [f"{self.prefix}/prio/+/+/fwd/{self.keys.party}"]

    def session(self, key: tuple[int, int]) -> PrioHelper | None:
        """The open or finished session ``(segment, epoch)`` (None if unknown or forgotten).

        Parameters
        ----------
        key : (int, int)
        """
        if key in self.sessions:
            return self.sessions[key]
        return self.finished[key][1] if key in self.finished else None

    def _sender(self, s: int, e: int, topic: str, rest: list[str]) -> str | None:
        """The aggregator a message on ``topic`` must be signed by, None for a topic that is not for this helper."""
        topics = PrioTopics(self.prefix, s, e)
        if rest == ["fwd", self.keys.party] and topic == topics.fwd(self.keys.party):
            return self.params.leader_id
        if len(rest) == 2 and rest[0] == "agg" and rest[1] in self.params.aggregators and rest[1] != self.keys.party \
                and topic == topics.agg(rest[1]):
            return rest[1]
        return None

    def handle(self, topic: str, payload: bytes) -> list[Publish]:
        """Route one message to its session's helper (created on the first signed aggregator message).

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
        sender = self._sender(s, e, topic, rest)
        if sender is None or key in self.finished:
            return []
        h = self.sessions.get(key)
        if h is None:
            try:     # only the leader's own signed message on its canonical topic opens a session here
                open_signed(payload, self.trust, topic, sender)
            except (MessageError, ParameterError):
                return []
            if sender != self.params.leader_id:       # another helper's, early: kept until the leader opens it
                self._keep_early(key, topic, payload)
                return []
            if self.max_open is not None and len(self.sessions) >= self.max_open:
                if len(self.refused) < 1000:       # the first ones tell the operator enough
                    self.refused.append(f"session {s}/{e} refused: {self.max_open} sessions are open")
                return []
            h = self.sessions[key] = PrioHelper(self.prefix, s, e, self.params, self.trust, self.keys, self.log,
                                                self._rng)
            self._heard[key] = self._clock()
        before = len(h.events)
        out = h.handle(topic, payload)
        early = self._early.pop(key, [])
        self._early_bytes -= sum(len(p) for _, p in early)
        for t, p in early:
            out += h.handle(t, p)
        if not any(kind == "refused" for kind, _ in h.events[before:]):
            self._heard[key] = self._clock()          # a refused message keeps no session alive
        del h.events[MAX_EVENTS:]
        if h.done or h.closed:
            self._finish(key, "finished")
        return out

    def _keep_early(self, key: tuple[int, int], topic: str, payload: bytes) -> None:
        """Keep another helper's signed message for a session the leader has not opened yet, within
        :data:`MAX_EARLY_PEER` per session, :data:`MAX_EARLY_SESSIONS` sessions and
        :data:`MAX_EARLY_PEER_BYTES` in all: the oldest sessions' messages make room (a helper that floods
        loses its own early messages, which the leader's session then waits for or aborts on)."""
        if len(payload) > MAX_EARLY_PEER_BYTES:
            return
        early = self._early.setdefault(key, [])
        if len(early) >= MAX_EARLY_PEER:
            return
        early.append((topic, bytes(payload)))
        self._early_bytes += len(payload)
        while len(self._early) > MAX_EARLY_SESSIONS or self._early_bytes > MAX_EARLY_PEER_BYTES:
            _, dropped = self._early.popitem(last=False)
            self._early_bytes -= sum(len(p) for _, p in dropped)

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
    """A helper as a long-running party of a fleet (``roadcollab helper``): it advertises its key (retained,
    signed by its certified identity) and answers every session through a :class:`PrioHelperService`. Has
    the service's loop interface (``on_connect``, ``tick``, ``handle``,
    :func:`~roadcollab.network.mqtt_run.run_service`).

    Parameters
    ----------
    prefix : str
    params : PrioParams
    trust : FleetTrust
    keys : AggregatorKeys
        The helper's identity and X25519 key.
    log : ReleaseLog
    on_event : callable, optional
        One line per event (a session finished, a refusal).
    """

    def __init__(self, prefix: str, params: PrioParams, trust: FleetTrust, keys: AggregatorKeys, log: ReleaseLog,
                 on_event=None) -> None:
        self.prefix, self.params, self.trust, self.keys, self.log = prefix, params, trust, keys, log
        self.service = PrioHelperService(prefix, params, trust, keys, log)
        self._event = on_event or (lambda line: None)

    @property
    def subscriptions(self) -> list[str]:
        return self.service.subscriptions

    def on_connect(self) -> list[Publish]:
        """Its key advert, retained (again after every connection)."""
        return [Publish(key_topic(self.prefix, self.keys.party), self.keys.advert(self.prefix), retain=True)]

    def tick(self) -> list[Publish]:
        """Ends the sessions idle for too long (:meth:`PrioHelperService.expire`); publishes nothing."""
        for s, e in self.service.expire():
            self._event(f"session {s}/{e}: no message for {self.service.max_idle_s:.0f} s, ended")
        return []

    def handle(self, topic: str, payload: bytes) -> list[Publish]:
        """A session message of an aggregator; what to publish (nothing raises).

        Parameters
        ----------
        topic : str
        payload : bytes
        """
        try:
            key = PrioTopics.parse(self.prefix, topic)[:2]
        except MessageError:
            return []
        known, refused = key in self.service.finished, len(self.service.refused)
        out = self.service.handle(topic, payload)
        if not known and key in self.service.finished:
            why = self.service.finished[key][1]
            self._event(f"session {key[0]}/{key[1]}: {'finished' if why.finished else 'closed'}")
        if len(self.service.refused) > refused:
            self._event(self.service.refused[-1])
        return out
