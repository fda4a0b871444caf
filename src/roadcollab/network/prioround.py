"""The leader of validated, phased sessions between parties (issue 20, section 2): the roadside service.

The protocol is :mod:`.prioaggregator`'s (every aggregator's steps); :class:`PrioLeader` is aggregator ``A``,
which also invites the vehicles, takes their uploads, forwards each helper's sealed share and relays the
results every aggregator signed. Its ``advance`` is its timeout: it closes the uploads of the phase with
what arrived, or gives up on the helpers. Parameters and signed results: :mod:`.prioparams`.
"""

from __future__ import annotations

import numpy as np

from ..errors import MessageError, ParameterError
from ..privacy.secagg_store import ReleaseLog
from ..wire.certificate import check_id, verify_signature
from ..wire.identity import FleetTrust
from .messages import open_signed, seal
from .prioaggregator import PrioAggregator, _Phase
from .prioparams import MAX_EVENTS, PrioParams, closed_notices, open_result, result_bundle
from .priowire import AggregatorKeys, open_advert, pack, result_bytes, unpack
from .service import Publish

__all__ = ["PrioParams", "PrioAggregator", "PrioLeader", "closed_notices", "result_bundle", "open_result"]


class PrioLeader(PrioAggregator):
    """Aggregator ``A`` of one session: also the vehicles' only contact (module docstring).

    Parameters
    ----------
    prefix : str
        Topic prefix (``rc/{fleet_id}``).
    segment, epoch : int
        The measurement.
    params : PrioParams
    trust : FleetTrust
    keys : AggregatorKeys
        ``A``'s identity (id ``params.leader_id``) and X25519 key.
    helper_adverts : dict or sequence of bytes
        Every helper's signed key advert (checked; relayed to every vehicle with each invite).
    log : ReleaseLog
        ``A``'s persistent record of released sums.
    rng : numpy.random.Generator, optional
        Its coins (tests).

    Attributes
    ----------
    state : str
        ``"new"``, ``"running"``, ``"finished"`` or ``"aborted"``.
    result : (L,) ndarray or None
        ``m_K`` once finished.
    pid : dict
        Vehicle id to protocol id.
    answered : set of int
        Protocol ids whose phase-1 upload arrived signed: those vehicles have spent the measurement
        (their ledgers recorded it before they sent it), accepted or not.
    """

    def __init__(self, prefix: str, segment: int, epoch: int, params: PrioParams, trust: FleetTrust,
                 keys: AggregatorKeys, helper_adverts, log: ReleaseLog, rng: np.random.Generator | None = None) -> None:
        if keys.party != params.leader_id:
            raise ParameterError(f"the leader's identity is {keys.party!r}, expected {params.leader_id!r}")
        adverts = list(helper_adverts.values()) if isinstance(helper_adverts, dict) else list(helper_adverts)
        if len(adverts) != len(params.helper_ids):
            raise ParameterError(f"one key advert per helper {list(params.helper_ids)}, got {len(adverts)}")
        self.helper_adverts = [bytes(a) for a in adverts]
        self.helper_keys = {h: open_advert(a, trust, prefix, h)[1] for h, a in zip(params.helper_ids, self.helper_adverts)}
        super().__init__(prefix, segment, epoch, params, trust, keys, log, rng)
        self._advert = keys.advert(prefix)
        self.state = "new"
        self.pid: dict[str, int] = {}
        self.answered: set[int] = set()
        self.result: np.ndarray | None = None
        self._bundle = b""
        self._uploaded: set[int] = set()

    @property
    def expected(self) -> tuple[int, ...]:
        """Protocol ids expected in this phase: the roster in phase 1, phase 1's accepted set after."""
        return self._expected()

    def _invite(self, vid: str) -> Publish:
        i, k = self.pid[vid], self.phase
        head = {"t": "invite", "phase": k, "id": i, "roster": sorted(self.pid.values())}
        return Publish(self.topics.to(vid), pack(head, self._advert, *self.helper_adverts, self._bundle))

    def open(self, roster: list[str]) -> list[Publish]:
        """Invite the certified vehicles ``roster`` (vehicle ids; protocol ids ``1..n`` in that order).

        Parameters
        ----------
        roster : list of str
        """
        if self.state != "new" or not roster or len(set(roster)) != len(roster):
            raise ParameterError("open: once, with a non-empty list of distinct vehicle ids")
        self.pid = {check_id("vehicle id", v): i + 1 for i, v in enumerate(roster)}
        self.roster = {i: v for v, i in self.pid.items()}
        self.state = "running"
        return [self._send("open", 1, {"roster": self.pid})] + self._progress() + [self._invite(v) for v in self.pid]

    def handle(self, topic: str, payload: bytes) -> list[Publish]:
        """Apply one message (a vehicle's upload or a helper's); what to publish.

        Parameters
        ----------
        topic : str
        payload : bytes
        """
        rest = topic[len(self.topics.base) + 1:].split("/") if topic.startswith(self.topics.base + "/") else []
        try:
            if len(rest) == 2 and rest[0] == "agg" and rest[1] in self.params.helper_ids:
                if self.state != "running":
                    raise MessageError(f"session is {self.state}")
                return self._from_aggregator(rest[1], topic, payload) + self._settle()
            if len(rest) == 2 and rest[0] == "up":
                return self._upload(topic, rest[1], payload) + self._settle()
            return []
        except (MessageError, ParameterError) as err:
            self.events.append(("refused", f"{topic}: {str(err)[:300]}"))
            del self.events[MAX_EVENTS:]
            return []

    def _upload(self, topic: str, vid: str, payload: bytes) -> list[Publish]:
        ph, k = self._ph, self.phase
        if self.state != "running" or ph.closed is not None:
            raise MessageError(f"no upload is taken now (session {self.state}, phase {k})")
        if vid not in self.pid:
            raise MessageError(f"{vid} is not in the roster")
        cert, body = open_signed(payload, self.trust, topic, vid)
        h, blobs = unpack(body, "upload")
        i = self.pid[vid]
        if h.get("t") != "upload" or h.get("phase") != k or h.get("id") != i or len(blobs) != 1 + self.count:
            raise MessageError(f"expected the upload of phase {k} of protocol id {i} ({1 + self.count} parts)")
        if i not in self.expected:
            raise MessageError(f"{vid} is not in phase {k}'s set")
        if i in self._uploaded:
            self.events.append(("duplicate", f"{topic}: upload of phase {k} again (applied once)"))
            return []
        self._uploaded.add(i)
        if k == 1:
            self.answered.add(i)
        self._receive(i, cert, blobs[0], blobs[1], k)
        out = [Publish(self.topics.fwd(party), seal(self.keys.identity, self.topics.fwd(party),
                                                    pack({"t": "fwd", "phase": k, "id": i}, sealed, blobs[0],
                                                         cert.to_bytes())))
               for party, sealed in zip(self.params.helper_ids, blobs[2:])]
        if all(j in self._uploaded for j in self.expected):
            out += self._close()
        return out

    def _close(self) -> list[Publish]:
        ph = self._ph
        ph.closed = tuple(sorted(self._uploaded))
        return [self._send("close", self.phase, {"ids": list(ph.closed)})] + self._progress()

    def advance(self) -> list[Publish]:
        """The leader's timeout: close the phase's uploads with what arrived, or give up on the helpers.

        Returns
        -------
        list of Publish
        """
        if self.state != "running":
            return []
        if self._ph.closed is None:
            return self._close() + self._settle()
        ph = self._ph
        kind, silent = next(((kind, [p for p in self.params.aggregators if p not in store])
                             for kind, store in (("commit", ph.commits), ("reveal", ph.reveals), ("vshares", ph.reports),
                                                 ("set", ph.sets), ("sums", ph.sums), ("result", ph.results))
                             if len(store) < self.count), ("result", []))
        return self._abort(f"phase {self.phase}: no {kind} from {silent} in time") + self._settle()

    def _after_result(self, ph: _Phase) -> list[Publish] | None:
        if len(ph.results) < self.count:
            return None
        mb = ph.results[self.party][0]
        sigs = []
        for party in self.params.aggregators:
            m, sig = ph.results[party]
            try:
                if m != mb:
                    raise MessageError("another m")
                verify_signature(self.certificates[party].public_key, result_bytes(self.session, ph.k, ph.accepted, m),
                                 sig, f"{party}'s result")
            except MessageError as err:
                return self._abort(f"phase {ph.k}: {party}'s result is not this aggregator's ({err})")
            sigs.append(sig)
        self._bundle = result_bundle(ph.k, ph.accepted, mb, sigs)
        self._m = ph.m
        if ph.k == self.params.phases:
            self.result = ph.m
            self.finished = True
            reason = f"{len(self.accepted)} inputs over {ph.k} phases, refused {sorted(self.refused)}"
            self.events.append(("finished", reason))
            return []
        self.phase += 1
        self._phases.setdefault(self.phase, self._new_phase(self.phase))
        del self._phases[ph.k]
        self._uploaded = set()
        return [self._invite(self.roster[i]) for i in self.accepted]

    def _abort(self, reason: str) -> list[Publish]:
        if self.done:
            return []
        self.aborted = True
        self.events.append(("aborted", reason))
        return []

    def _on_peer_abort(self) -> list[Publish]:
        return []

    def _settle(self) -> list[Publish]:
        """The session's end, once: ``closed`` to the helpers and the roster."""
        if self.state != "running" or not self.done:
            return []
        self.state = "finished" if self.finished else "aborted"
        reason = next((r for kind, r in reversed(self.events) if kind in ("finished", "aborted")), self.state)
        return closed_notices(self.topics, self.keys, list(self.pid), self.state, reason, self.accepted, self.phase)
