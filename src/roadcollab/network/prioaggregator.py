"""Validated, phased secure aggregation as messages between separate parties (issue 20, section 2).

This module holds what every aggregator runs (:class:`PrioAggregator`); the leader is :class:`.prioround.PrioLeader`,
the helpers :class:`.priohelper.PrioHelper`.

The phased sessions of :mod:`roadcollab.privacy.secagg_phased` (every input proven inside a public box in
phase 1, then deviations from the previous result proven inside an l2 ball: centred clipping) with two or
three aggregators (:mod:`roadcollab.privacy.secagg_replicated`), each a separate party:

- the **leader** ``A`` (:class:`~.prioround.PrioLeader`, the roadside service) invites the vehicles, receives their
  uploads, checks its share of every proof and forwards each helper's share, sealed to that helper, unread;
- the **helpers** ``B`` and ``C`` (:class:`~.priohelper.PrioHelper`, other operators such as the road
  agency) check their shares of every proof;
- each **vehicle** (:class:`~.prioagent.PrioAgent`) records the measurement in its
  :class:`~roadcollab.privacy.secagg_store.SessionLedger` before phase 1 (a second session on it gets
  nothing), checks every aggregator's signature on the previous result and records phase 1's set, then
  proves its clipped deviation.

Every aggregator runs the same steps per phase (:class:`PrioAggregator`), each on its own view and each
signed: ``commit`` to a random coin; once the leader ``close``s the phase's uploads and every commitment is
in, ``reveal`` the coin (the proofs' query randomness is their hash, so no party knew it while uploads were
open); ``vshares`` (its verifier shares of every closed vehicle); ``set`` (the accepted set it computes from
everyone's verifier shares: the two holders of a component must agree, else it aborts); ``sums`` (its
components' sums, only once every aggregator announced the same set, recorded in its
:class:`~roadcollab.privacy.secagg_store.ReleaseLog` first: once per (session, phase), after phase 1 only
over phase 1's set); ``result`` (``m_k``, signed, only if the two holders of every component report the
same sum). Vehicles act on a result only with every aggregator's signature. With three aggregators one of
them may deviate in any way: it is caught before it can change a decision, a set or a result, and it sees
one component less than the input (docs/security-secagg.md).

Messages and topics: :mod:`.priowire`. Every party is a state machine over ``(topic, payload)``; nothing a
party receives raises out of ``handle``: a refused message is recorded in ``events``.
"""

from __future__ import annotations

import hashlib
import json
import os

import numpy as np

from ..errors import MessageError, ParameterError
from ..privacy.secagg_messages import AggregationRefused, session_id
from ..privacy.secagg_phased import phase_session
from ..privacy.secagg_replicated import ReplicatedAggregator, Verification, coin_commitment, coin_key, holdings
from ..privacy.secagg_replicated_run import combine_sums, combine_verifications
from ..privacy.secagg_store import ReleaseLog
from ..wire.certificate import Certificate
from ..wire.identity import FleetTrust
from .messages import open_signed, seal
from .prioparams import PrioParams
from .priowire import AggregatorKeys, PrioTopics, elements, ids_field, int_field, pack, read_commitments, \
    read_share, result_bytes, unpack
from .service import Publish

__all__ = ["PrioAggregator"]


class _Phase:
    """One phase at one aggregator: its coin, what it received of every aggregator, what it sent."""

    def __init__(self, k: int, agg: ReplicatedAggregator, coin: bytes) -> None:
        self.k, self.agg, self.coin = k, agg, coin
        self.closed: tuple[int, ...] | None = None
        self.commits: dict[str, bytes] = {}
        self.reveals: dict[str, bytes] = {}
        self.reports: dict[str, dict[int, Verification | str]] = {}
        self.sets: dict[str, tuple[int, ...]] = {}
        self.sums: dict[str, dict[int, np.ndarray]] = {}
        self.results: dict[str, tuple[bytes, bytes]] = {}
        self.views: dict[str, bytes] = {}
        self.raw: dict[int, bytes] = {}
        self.rejected: dict[int, str] = {}
        self.accepted: tuple[int, ...] | None = None
        self.m: np.ndarray | None = None


class PrioAggregator:
    """What every aggregator of one session runs: the coin toss, the checks, the agreement, the sums.

    Parameters
    ----------
    prefix : str
        Topic prefix (``rc/{fleet_id}``).
    segment, epoch : int
        The measurement.
    params : PrioParams
    trust : FleetTrust
    keys : AggregatorKeys
        This aggregator's identity (one of ``params.aggregators``) and X25519 key.
    log : ReleaseLog
        This aggregator's persistent record of released sums.
    rng : numpy.random.Generator, optional
        Its coins (tests); default the operating system's entropy.

    Attributes
    ----------
    phase : int
        The phase being run (1-based).
    accepted : tuple of int
        Phase 1's accepted set (protocol ids).
    refused : dict
        Protocol id to why it was not counted.
    events : list of (str, str)
        ``refused``, ``duplicate``, ``released``, ``aborted``, ``finished``, ``closed``.
    """

    def __init__(self, prefix: str, segment: int, epoch: int, params: PrioParams, trust: FleetTrust,
                 keys: AggregatorKeys, log: ReleaseLog, rng: np.random.Generator | None = None) -> None:
        if keys.party not in params.aggregators:
            raise ParameterError(f"{keys.party!r} is not one of the aggregators {list(params.aggregators)}")
        self.params, self.trust, self.keys, self.log = params, trust, keys, log
        self.party = keys.party
        self.index = params.aggregators.index(self.party)
        self.count = len(params.aggregators)
        self.comps = holdings(self.count)[self.index]
        self.topics = PrioTopics(prefix, segment, epoch)
        self.session = session_id(segment, epoch)
        self._rng = rng
        self.phase = 1
        self.events: list[tuple[str, str]] = []
        self.accepted: tuple[int, ...] = ()
        self.refused: dict[int, str] = {}
        self.roster: dict[int, str] = {}
        self.certificates: dict[str, Certificate] = {self.party: keys.identity.certificate}
        self.finished = False
        self.aborted = False
        self._m: np.ndarray | None = None
        self._seen: dict[tuple[int, str, str], bytes] = {}
        self._phases = {1: self._new_phase(1)}

    # -- the phase's state -------------------------------------------------------------------------------

    def _new_phase(self, k: int) -> _Phase:
        coin = self._rng.bytes(32) if self._rng is not None else os.urandom(32)
        return _Phase(k, ReplicatedAggregator(self.params.encoding(k), self.index, self.count), coin)

    @property
    def _ph(self) -> _Phase:
        return self._phases[self.phase]

    @property
    def done(self) -> bool:
        return self.finished or self.aborted

    def _psession(self, k: int) -> bytes:
        return phase_session(self.session, k)

    def _send(self, kind: str, k: int, header: dict | None = None, *blobs: bytes) -> Publish:
        topic = self.topics.agg(self.party)
        body = pack(dict(header or {}, t=kind, phase=k), *blobs)
        return Publish(topic, seal(self.keys.identity, topic, body))

    def _abort(self, reason: str) -> list[Publish]:
        """Stop here and tell the others (the leader overrides: it also tells the vehicles)."""
        if self.done:
            return []
        self.aborted = True
        self.events.append(("aborted", reason))
        return [self._send("abort", self.phase, {"reason": reason[:300]})]

    # -- messages of the other aggregators ---------------------------------------------------------------

    def _from_aggregator(self, party: str, topic: str, payload: bytes) -> list[Publish]:
        """Apply one signed message of aggregator ``party`` (MessageError if refused)."""
        cert, body = open_signed(payload, self.trust, topic, party)
        self.certificates.setdefault(party, cert)
        h, blobs = unpack(body, f"{party}'s message")
        kind = h.get("t")
        if self.done:
            raise MessageError(f"the session is {'aborted' if self.aborted else 'finished'}")
        if kind == "abort":
            self.aborted = True
            self.events.append(("aborted", f"{party} aborted: {str(h.get('reason'))[:300]}"))
            return self._on_peer_abort()
        if kind == "closed":
            return self._on_closed(party, h)
        k = int_field(h, "phase", f"{party}'s message", 1)
        if kind == "result" and k == self.phase - 1:
            return []         # a helper moves on once it has signed: the others' results are the leader's to check
        if not self.phase <= k <= min(self.phase + 1, self.params.phases):
            raise MessageError(f"a message of phase {k} in phase {self.phase}")
        # One message of each kind per party and phase: a second, different one is equivocation (a party
        # that shows two views, e.g. two coins, could get a proof queried at two points), a copy is a redelivery.
        digest = hashlib.sha256(body).digest()
        seen = self._seen.setdefault((k, party, str(kind)), digest)
        if seen != digest:
            return self._abort(f"phase {k}: {party} sent two different {kind!r} messages")
        if seen is not digest:
            self.events.append(("duplicate", f"{party}'s {kind} of phase {k} again (applied once)"))
            return []
        ph = self._phases.setdefault(k, self._new_phase(k))
        if kind == "open":
            self._on_open(party, h)
        elif kind == "close":
            if party != self.params.leader_id or ph.closed is not None:
                raise MessageError("a close that is not the leader's first of the phase")
            ph.closed = ids_field(h, "ids", "close")
        elif kind in ("commit", "reveal", "view"):
            store = {"commit": ph.commits, "reveal": ph.reveals, "view": ph.views}[kind]
            if len(blobs) != 1 or len(blobs[0]) != 32:
                raise MessageError(f"{kind}: expected 32 bytes")
            store[party] = bytes(blobs[0])
        elif kind == "vshares":
            ph.reports[party] = self._read_vshares(party, h, blobs, k)
        elif kind == "set":
            ph.sets[party] = ids_field(h, "accepted", "set")
        elif kind == "sums":
            ph.sums[party] = self._read_sums(party, h, blobs, k)
        elif kind == "result":
            if len(blobs) != 2:
                raise MessageError("result: expected m and the signature")
            ids_field(h, "accepted", "result")
            ph.results[party] = (bytes(blobs[0]), bytes(blobs[1]))
        else:
            raise MessageError(f"unknown message {kind!r}")
        return self._progress()

    def _on_open(self, party: str, h: dict) -> None:
        raise MessageError("open is the leader's")

    def _on_closed(self, party: str, h: dict) -> list[Publish]:
        raise MessageError("closed is the leader's")

    def _on_peer_abort(self) -> list[Publish]:
        return []

    def _read_vshares(self, party: str, h: dict, blobs: list[bytes], k: int) -> dict[int, Verification | str]:
        ids = ids_field(h, "ids", "vshares")
        why = h.get("refused")
        if not isinstance(why, dict) or not all(isinstance(v, str) for v in why.values()):
            raise MessageError("vshares: 'refused' must map ids to reasons")
        refused = {int(i): str(v)[:300] for i, v in why.items() if i.isascii() and i.isdigit() and len(i) <= 9}
        comps = holdings(self.count)[self.params.aggregators.index(party)]
        enc = self.params.encoding(k)
        width = 2 * enc.chunk + 3
        checked = [i for i in ids if i not in refused]
        if len(blobs) != 2 or len(blobs[0]) != 32 * len(checked):
            raise MessageError("vshares: expected the joint randomness of every checked vehicle and the values")
        vals = elements(enc.field, blobs[1], "verifier shares", len(checked) * len(comps) * width)
        out: dict[int, Verification | str] = dict(refused)
        for n, i in enumerate(checked):
            row = vals[n * len(comps) * width:(n + 1) * len(comps) * width]
            out[i] = Verification(i, bytes(blobs[0][32 * n:32 * (n + 1)]),
                                  {j: row[c * width:(c + 1) * width] for c, j in enumerate(comps)})
        return out

    def _read_sums(self, party: str, h: dict, blobs: list[bytes], k: int) -> dict[int, np.ndarray]:
        ids_field(h, "accepted", "sums")
        comps = holdings(self.count)[self.params.aggregators.index(party)]
        enc = self.params.encoding(k)
        if len(blobs) != 1:
            raise MessageError("sums: expected one part")
        vals = elements(enc.field, blobs[0], "sums", len(comps) * enc.length)
        return {j: vals[c * enc.length:(c + 1) * enc.length] for c, j in enumerate(comps)}

    def _receive(self, i: int, cert: Certificate, commitments_b: bytes, share: bytes, k: int) -> None:
        """Check and keep this aggregator's share of vehicle ``i``'s upload (a failure is its refusal)."""
        ph = self._phases[k]
        ph.raw[i] = bytes(commitments_b)          # what this aggregator saw, in its view of the phase
        try:
            if cert.vehicle_id != self.roster.get(i):
                raise MessageError(f"the certificate is {cert.vehicle_id}'s, not {self.roster.get(i)}'s")
            c = read_commitments(commitments_b, i, self.count)
            sh = read_share(share, self.comps, self.params.encoding(k), f"vehicle {i}'s share")
            ph.agg.receive(c, sh, self._psession(k), self.trust, cert)
        except (MessageError, ValueError, TypeError, ArithmeticError) as err:     # the vehicle's fault: refused
            ph.rejected[i] = f"vehicle {i}: {err}"[:300] if isinstance(err, MessageError) else \
                f"vehicle {i}: a malformed share ({type(err).__name__})"

    # -- this aggregator's steps ---------------------------------------------------------------------------

    def _ready_to_reveal(self, ph: _Phase) -> bool:
        """Whether every closed vehicle's upload was received here (or refused)."""
        assert ph.closed is not None
        return all(i in ph.agg.held or i in ph.rejected for i in ph.closed)

    def _progress(self) -> list[Publish]:
        """Take every step the messages so far allow."""
        out: list[Publish] = []
        while not self.done:
            step = self._step(self._ph)
            if step is None:
                break
            out += step
        return out

    def _step(self, ph: _Phase) -> list[Publish] | None:
        n, k, me = self.count, ph.k, self.party
        if me not in ph.commits:
            ph.commits[me] = coin_commitment(self._psession(k), me, ph.coin)
            return [self._send("commit", k, {}, ph.commits[me])]
        if me not in ph.reveals:
            if ph.closed is None or len(ph.commits) < n or not self._ready_to_reveal(ph):
                return None
            try:      # one coin per (session, phase), ever: no proof gets a second query point
                self.log.coin(self.session, k)
            except AggregationRefused as err:
                return self._abort(f"phase {k}: {err}")
            ph.reveals[me] = ph.coin
            return [self._send("reveal", k, {}, ph.coin)]
        if me not in ph.views:
            if len(ph.reveals) < n:
                return None
            for party in self.params.aggregators:
                if coin_commitment(self._psession(k), party, ph.reveals[party]) != ph.commits[party]:
                    return self._abort(f"phase {k}: {party}'s coin does not open its commitment")
            ph.views[me] = self._view(ph)
            return [self._send("view", k, {}, ph.views[me])]
        if me not in ph.reports:
            if len(ph.views) < n:
                return None
            other = next((p for p in self.params.aggregators if ph.views[p] != ph.views[me]), None)
            if other is not None:
                return self._abort(f"phase {k}: {other} saw another phase (roster, uploads, commitments or coins)")
            return self._vshares(ph)
        if ph.accepted is None:
            if len(ph.reports) < n:
                return None
            return self._set(ph)
        if me not in ph.sums:
            if len(ph.sets) < n:
                return None
            return self._sums(ph)
        if me not in ph.results:
            if len(ph.sums) < n:
                return None
            return self._result(ph)
        return self._after_result(ph)

    def _view(self, ph: _Phase) -> bytes:
        """The digest of what this aggregator's verifier shares rest on: the roster, the closed uploads'
        commitments and every coin's commitment and opening. The aggregators send verifier shares only once
        all three digests agree, so the honest ones query every proof at one and the same point."""
        assert ph.closed is not None
        m = hashlib.sha256(b"roadcollab/prio/view/v1|" + self._psession(ph.k))
        m.update(json.dumps(sorted(self.roster.items())).encode())
        for i in ph.closed:
            m.update(i.to_bytes(4, "little") + hashlib.sha256(ph.raw.get(i, b"")).digest())
        for party in self.params.aggregators:
            m.update(ph.commits[party] + ph.reveals[party])
        return m.digest()

    def _vshares(self, ph: _Phase) -> list[Publish]:
        k = ph.k
        key = coin_key(self._psession(k), [ph.reveals[p] for p in self.params.aggregators])
        assert ph.closed is not None
        report: dict[int, Verification | str] = {}
        for i in ph.closed:
            report[i] = ph.rejected[i] if i in ph.rejected else ph.agg.verify(i, self._psession(k), key)
        ph.reports[self.party] = report
        checked = [i for i in ph.closed if isinstance(report[i], Verification)]
        f = self.params.encoding(k).field
        joints = b"".join(report[i].joint for i in checked)                       # type: ignore[union-attr]
        values = [v for i in checked for j in self.comps for v in report[i].values[j]]  # type: ignore[union-attr]
        head = {"ids": list(ph.closed), "refused": {str(i): r for i, r in ph.rejected.items() if i in ph.closed}}
        return [self._send("vshares", k, head, joints, f.to_bytes(np.array(values, dtype=object)))]

    def _set(self, ph: _Phase) -> list[Publish]:
        k = ph.k
        assert ph.closed is not None
        acc, refused, conflicts = combine_verifications(self.params.encoding(k), self.count, ph.closed,
                                                        [ph.reports[p] for p in self.params.aggregators])
        if conflicts:
            return self._abort(f"phase {k}: {conflicts[0]} (an aggregator deviated)")
        for i in self._expected():
            why = refused.get(i, "" if i in acc else f"vehicle {i}: no upload in phase {k}")
            if why:
                self.refused.setdefault(i, why)
        if k > 1 and acc != self.accepted:
            return self._abort(f"phase {k}: vehicles {sorted(set(self.accepted) - set(acc))} were refused or sent "
                               "nothing; nothing after phase 1 is revealed")
        if len(acc) < self.params.min_inputs:
            return self._abort(f"phase {k}: {len(acc)} inputs accepted, {self.params.min_inputs} required")
        ph.accepted = ph.sets[self.party] = acc
        return [self._send("set", k, {"accepted": list(acc)})]

    def _sums(self, ph: _Phase) -> list[Publish]:
        k, acc = ph.k, ph.accepted
        assert acc is not None
        other = next((p for p in self.params.aggregators if ph.sets[p] != acc), None)
        if other is not None:
            return self._abort(f"phase {k}: {other} announced another accepted set")
        try:
            self.log.release(self.session, k, acc)
            sums = ph.agg.component_sums(acc, self.params.min_inputs)
        except AggregationRefused as err:
            return self._abort(f"phase {k}: {err}")
        ph.sums[self.party] = sums
        self.events.append(("released", f"phase {k} over {len(acc)} vehicles"))
        f = self.params.encoding(k).field
        blob = f.to_bytes(np.concatenate([sums[j] for j in self.comps]))
        return [self._send("sums", k, {"accepted": list(acc)}, blob)]

    def _result(self, ph: _Phase) -> list[Publish]:
        k, acc, enc = ph.k, ph.accepted, self.params.encoding(ph.k)
        assert acc is not None
        try:
            total = combine_sums(enc, self.count, [ph.sums[p] for p in self.params.aggregators])
        except MessageError as err:
            return self._abort(f"phase {k}: {err}")
        avg = enc.decode_sum(total, len(acc)) / len(acc)
        ph.m = avg if k == 1 or self._m is None else self._m + avg
        mb = ph.m.astype("<f8").tobytes()
        sig = self.keys.identity.sign(result_bytes(self.session, k, acc, mb))
        ph.results[self.party] = (mb, sig)
        if k == 1:
            self.accepted = acc
        return [self._send("result", k, {"accepted": list(acc)}, mb, sig)]

    def _after_result(self, ph: _Phase) -> list[Publish] | None:
        """A helper moves on once it has signed; the leader waits for every signature (:class:`PrioLeader`)."""
        self._m = ph.m
        if ph.k == self.params.phases:
            self.finished = True
            self.events.append(("finished", f"{len(self.accepted)} inputs over {ph.k} phases"))
            return []
        self.phase += 1
        self._phases.setdefault(self.phase, self._new_phase(self.phase))
        del self._phases[ph.k]
        return []

    def _expected(self) -> tuple[int, ...]:
        """Protocol ids expected in this phase: the roster in phase 1, phase 1's accepted set after."""
        return tuple(sorted(self.roster)) if self.phase == 1 else self.accepted
