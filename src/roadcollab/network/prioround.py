"""Validated, phased secure aggregation as messages between separate parties (issue 20, section 2).

The phased sessions of :mod:`roadcollab.privacy.secagg_phased` (every input proven inside a public box in
phase 1, then deviations from the previous result proven inside an l2 ball: centred clipping), with the
two aggregators of :mod:`roadcollab.privacy.secagg_validity` as separate processes:

- the **leader** ``A`` (:class:`PrioLeader`, the roadside service) invites the vehicles, receives their
  uploads, checks its share of every proof and relays each vehicle's helper part, sealed to ``B``, unread;
- the **helper** ``B`` (:class:`~.priohelper.PrioHelper`, a second operator such as the road agency)
  opens the sealed parts, checks its share of every proof, and releases its sum share only over a set of
  vehicles it checked itself, once per (session, phase) and, after phase 1, only over phase 1's set
  (:class:`~roadcollab.privacy.secagg_store.ReleaseLog`, persisted); it signs every phase's result;
- each **vehicle** (:class:`~.prioagent.PrioAgent`) records the measurement in its
  :class:`~roadcollab.privacy.secagg_store.SessionLedger` before phase 1 (a second session on it gets
  nothing), checks the helper's signature on the previous result and records phase 1's set, then proves
  its clipped deviation.

Messages and topics: :mod:`.priowire`. Every party is a state machine over ``(topic, payload)``; nothing a
party receives raises out of ``handle``: a refused message is recorded in ``events``. The leader's
``advance`` is its timeout: it closes the phase with the vehicles decided by then. Threat model
(docs/security-secagg.md): any vehicles may deviate; at most one of ``A`` and ``B``; they do not collude.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import check_int
from ..errors import MessageError, ParameterError
from ..privacy.secagg_flp import Proof, ValidityEncoding
from ..privacy.secagg_messages import AggregationRefused, session_id
from ..privacy.secagg_phased import check_encodings, phase_session
from ..privacy.secagg_store import ReleaseLog
from ..privacy.secagg_validity import HelperUpload, LeaderUpload, Submission, ValidityAggregator, VerifierShare
from ..wire.certificate import check_id, verify_signature
from ..wire.identity import FleetTrust
from .messages import open_signed, seal
from .priowire import AggregatorKeys, PrioTopics, elements, ids_field, int_field, open_advert, pack, read_vshare, \
    result_bytes, unpack, verify_key, vshare_message
from .service import Publish

__all__ = ["PrioParams", "PrioAggregator", "PrioLeader", "closed_notices"]


@dataclass(frozen=True)
class PrioParams:
    """Public parameters of a phased session, the same for every party.

    Attributes
    ----------
    wide : ValidityEncoding
        Phase 1's box.
    tight : tuple of ValidityEncoding
        Phases ``2..K`` (each with a norm bound; :func:`~roadcollab.privacy.secagg_phased.radius_schedule`).
    min_inputs : int
        ``k``: no sum over fewer accepted vehicles is released.
    leader_id, helper_id : str
        Certificate ids of the two aggregators (the fleet authority issues them to no vehicle).
    """

    wide: ValidityEncoding
    tight: tuple[ValidityEncoding, ...] = ()
    min_inputs: int = 2
    leader_id: str = "aggregator-a"
    helper_id: str = "aggregator-b"

    def __post_init__(self) -> None:
        object.__setattr__(self, "tight", tuple(check_encodings(self.wide, list(self.tight), 1 + len(self.tight))))
        check_int("min_inputs", self.min_inputs, low=1)
        check_id("leader_id", self.leader_id)
        check_id("helper_id", self.helper_id)
        if self.leader_id == self.helper_id:
            raise ParameterError("leader_id and helper_id must differ")

    @property
    def phases(self) -> int:
        """``K``."""
        return 1 + len(self.tight)

    def encoding(self, phase: int) -> ValidityEncoding:
        """The encoding of ``phase`` (MessageError outside ``1..K``).

        Parameters
        ----------
        phase : int
            1-based.
        """
        if not 1 <= phase <= self.phases:
            raise MessageError(f"phase {phase} is not in 1..{self.phases}")
        return self.wide if phase == 1 else self.tight[phase - 2]


def closed_notices(topics: PrioTopics, keys: AggregatorKeys, roster: list[str], outcome: str, reason: str,
                   accepted=(), phase: int = 1) -> list[Publish]:
    """The leader's ``closed`` notices of a session: to the helper (signed) and to every vehicle of ``roster``.

    Parameters
    ----------
    topics : PrioTopics
    keys : AggregatorKeys
        The leader's.
    roster : list of str
    outcome, reason : str
    accepted : sequence of int
        Phase 1's accepted set.
    phase : int
        The phase it closed in.
    """
    head = {"t": "closed", "outcome": outcome, "reason": reason, "accepted": list(accepted)}
    body = pack(dict(head, phase=phase))
    return [Publish(topics.leader, seal(keys.identity, topics.leader, body))] + \
        [Publish(topics.to(v), pack(head)) for v in roster]


class PrioAggregator:
    """What both aggregators of one session share: identities, the verify key, one phase's proof checks.

    Parameters
    ----------
    prefix : str
        Topic prefix (``rc/{fleet_id}``).
    segment, epoch : int
        The measurement.
    params : PrioParams
    trust : FleetTrust
    keys : AggregatorKeys
        This aggregator's identity (id ``params.leader_id`` or ``params.helper_id``) and X25519 key.
    peer_advert : bytes
        The other aggregator's signed key advert.
    log : ReleaseLog
        This aggregator's persistent record of released sum shares.
    """

    #: True for ``A`` (the shares of ``x`` and the proof in full), False for ``B`` (expanded from a seed).
    LEADER = True

    def __init__(self, prefix: str, segment: int, epoch: int, params: PrioParams, trust: FleetTrust,
                 keys: AggregatorKeys, peer_advert: bytes, log: ReleaseLog) -> None:
        own, peer = (params.leader_id, params.helper_id) if self.LEADER else (params.helper_id, params.leader_id)
        if keys.party != own:
            role = "leader" if self.LEADER else "helper"
            raise ParameterError(f"the {role}'s identity is {keys.party!r}, expected {own!r}")
        self.params, self.trust, self.keys, self.log = params, trust, keys, log
        self.topics = PrioTopics(prefix, segment, epoch)
        self.session = session_id(segment, epoch)
        self.peer_cert, peer_pub = open_advert(peer_advert, trust, prefix, peer)
        self._vkey = verify_key(keys.key, peer_pub, self.session)
        self.phase = 1
        self.events: list[tuple[str, str]] = []
        self._m: np.ndarray | None = None
        self._new_phase()

    def _new_phase(self) -> None:
        self._agg = ValidityAggregator(self.params.encoding(self.phase), self._vkey, self.LEADER)
        self._own: dict[int, VerifierShare] = {}
        self._peer: dict[int, VerifierShare] = {}
        self._decided: dict[int, str] = {}

    def _decide_pair(self, i: int) -> None:
        """Record vehicle ``i``'s decision once both verifier shares are in (``""``: accepted)."""
        if i in self._own and i in self._peer and i not in self._decided:
            why = self._agg.check(self._own[i], self._peer[i])
            self._decided[i] = f"vehicle {i}: {why}" if why else ""

    def _next_m(self, total: np.ndarray, n: int) -> np.ndarray:
        """``m_k`` from the combined sum shares of this phase's ``n`` accepted vehicles."""
        avg = self.params.encoding(self.phase).decode_sum(total, n) / n
        return avg if self.phase == 1 or self._m is None else self._m + avg


class PrioLeader(PrioAggregator):
    """Aggregator ``A`` of one session (module docstring).

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
    helper_advert : bytes
        ``B``'s signed key advert (relayed to every vehicle).
    log : ReleaseLog
        ``A``'s persistent record of released sum shares.

    Attributes
    ----------
    state : str
        ``"new"``, ``"running"``, ``"finished"`` or ``"aborted"``.
    phase : int
        The phase being run (1-based).
    result : (L,) ndarray or None
        ``m_K`` once finished.
    accepted : tuple of int
        Phase 1's accepted set (protocol ids).
    refused : dict
        Protocol id to why it was not counted.
    events : list of (str, str)
        ``(kind, reason)``: ``refused``, ``duplicate``, ``aborted``, ``finished``.
    answered : set of int
        Protocol ids whose phase-1 upload arrived signed: those vehicles have spent the measurement
        (their ledgers recorded it before they sent it), accepted or not.
    """

    def __init__(self, prefix: str, segment: int, epoch: int, params: PrioParams, trust: FleetTrust,
                 keys: AggregatorKeys, helper_advert: bytes, log: ReleaseLog) -> None:
        self.helper_advert = bytes(helper_advert)
        self.answered: set[int] = set()
        self.state = "new"
        self.pid: dict[str, int] = {}
        self.accepted: tuple[int, ...] = ()
        self.refused: dict[int, str] = {}
        self.result: np.ndarray | None = None
        self._signed = b""
        super().__init__(prefix, segment, epoch, params, trust, keys, self.helper_advert, log)

    def _new_phase(self) -> None:
        super()._new_phase()
        self._uploaded: set[int] = set()
        self._pending: tuple[tuple[int, ...], np.ndarray] | None = None

    @property
    def expected(self) -> tuple[int, ...]:
        """Protocol ids expected in this phase: the roster in phase 1, phase 1's accepted set after."""
        return tuple(sorted(self.pid.values())) if self.phase == 1 else self.accepted

    @property
    def done(self) -> bool:
        return self.state in ("finished", "aborted")

    def _to_helper(self, header: dict, *blobs: bytes) -> Publish:
        return Publish(self.topics.leader, seal(self.keys.identity, self.topics.leader, pack(header, *blobs)))

    def _invite(self, vid: str) -> Publish:
        i, k = self.pid[vid], self.phase
        head = {"t": "invite", "phase": k, "id": i, "roster": sorted(self.pid.values())}
        return Publish(self.topics.to(vid), pack(head, self.helper_advert, self._signed))

    def open(self, roster: list[str]) -> list[Publish]:
        """Invite the certified vehicles ``roster`` (vehicle ids; protocol ids ``1..n`` in that order).

        Parameters
        ----------
        roster : list of str
        """
        if self.state != "new" or not roster or len(set(roster)) != len(roster):
            raise ParameterError("open: once, with a non-empty list of distinct vehicle ids")
        self.pid = {check_id("vehicle id", v): i + 1 for i, v in enumerate(roster)}
        self.state = "running"
        return [self._to_helper({"t": "open", "roster": self.pid})] + [self._invite(v) for v in self.pid]

    def _refuse(self, reason: str) -> list[Publish]:
        self.events.append(("refused", reason))
        return []

    def handle(self, topic: str, payload: bytes) -> list[Publish]:
        """Apply one message (a vehicle's upload or the helper's); what to publish.

        Parameters
        ----------
        topic : str
        payload : bytes
        """
        rest = topic[len(self.topics.base) + 1:].split("/") if topic.startswith(self.topics.base + "/") else []
        try:
            if topic == self.topics.helper:
                return self._from_helper(topic, payload)
            if len(rest) == 2 and rest[0] == "up":
                return self._upload(topic, rest[1], payload)
            return []
        except (MessageError, ParameterError) as err:
            return self._refuse(f"{topic}: {err}")

    def _upload(self, topic: str, vid: str, payload: bytes) -> list[Publish]:
        if self.state != "running" or self._pending is not None:
            raise MessageError(f"no upload is taken now (session {self.state}, phase {self.phase})")
        if vid not in self.pid:
            raise MessageError(f"{vid} is not in the roster")
        cert, body = open_signed(payload, self.trust, topic, vid)
        h, blobs = unpack(body, "upload")
        i, k = self.pid[vid], self.phase
        if h.get("t") != "upload" or h.get("phase") != k or h.get("id") != i or len(blobs) != 6:
            raise MessageError(f"expected the upload of phase {k} of protocol id {i} (6 parts)")
        if i not in self.expected:
            raise MessageError(f"{vid} is not in phase {k}'s set")
        if i in self._uploaded:
            self.events.append(("duplicate", f"{topic}: upload of phase {k} again (applied once)"))
            return []
        self._uploaded.add(i)
        if k == 1:
            self.answered.add(i)
        enc = self.params.encoding(k)
        f = enc.field
        try:
            x = elements(f, blobs[0], f"vehicle {i}: x share", enc.length + enc.n_bits)
            proof = Proof(elements(f, blobs[1], f"vehicle {i}: proof share", enc.proof_length))
            sub = Submission(i, LeaderUpload(x, proof, blobs[2], blobs[3]), HelperUpload(b"", b"", b""), blobs[5])
            va = self._agg.prepare(sub, phase_session(self.session, k), self.trust, cert)
        except MessageError as err:
            self._decided[i] = f"vehicle {i}: {err}"
            return self._maybe_accept()
        self._own[i] = va
        head, values = vshare_message(va, f)
        return [self._to_helper({"t": "fwd", "phase": k, "id": i}, blobs[4], blobs[5], cert.to_bytes()),
                self._to_helper(dict(head, phase=k), values)] + self._decide(i)

    def _decide(self, i: int) -> list[Publish]:
        self._decide_pair(i)
        return self._maybe_accept()

    def _maybe_accept(self) -> list[Publish]:
        if self._pending is None and all(i in self._decided for i in self.expected):
            return self._accept()
        return []

    def advance(self) -> list[Publish]:
        """The leader's timeout: close the phase with the vehicles decided so far (or give up on the helper).

        Returns
        -------
        list of Publish
        """
        if self.state != "running":
            return []
        if self._pending is not None:
            return self._abort(f"phase {self.phase}: no result from the helper")
        return self._accept()

    def _accept(self) -> list[Publish]:
        k = self.phase
        acc = tuple(sorted(i for i, why in self._decided.items() if not why))
        for i in self.expected:
            why = self._decided.get(i, f"vehicle {i}: no upload checked by both aggregators in phase {k}")
            if why:
                self.refused.setdefault(i, why)
        if k > 1 and acc != self.accepted:
            return self._abort(f"phase {k}: vehicles {sorted(set(self.accepted) - set(acc))} were refused or sent "
                               "nothing; nothing after phase 1 is revealed")
        if len(acc) < self.params.min_inputs:
            return self._abort(f"phase {k}: {len(acc)} inputs accepted, {self.params.min_inputs} required")
        try:
            self.log.release(self.session, k, acc)
            share = self._agg.aggregate_share(acc, self.params.min_inputs)
        except AggregationRefused as err:
            return self._abort(f"phase {k}: {err}")
        self._pending = (acc, share)
        f = self.params.encoding(k).field
        return [self._to_helper({"t": "accept", "phase": k, "accepted": list(acc)}, f.to_bytes(share))]

    def _from_helper(self, topic: str, payload: bytes) -> list[Publish]:
        _, body = open_signed(payload, self.trust, topic, self.params.helper_id)
        h, blobs = unpack(body, "helper message")
        if self.state != "running":
            raise MessageError(f"session is {self.state}")
        if int_field(h, "phase", "helper message", 1) != self.phase:
            raise MessageError(f"a helper message of phase {h.get('phase')} in phase {self.phase}")
        kind = h.get("t")
        if kind == "refuse":
            return self._abort(f"phase {self.phase}: the helper refused: {str(h.get('reason'))[:300]}")
        if kind in ("vshare", "reject"):
            i = int_field(h, "id", "helper message", 1)
            if i not in self.expected or i in self._peer or i in self._decided and kind == "vshare":
                raise MessageError(f"a verifier share of vehicle {i} that is not expected")
            if kind == "reject":
                self._decided.setdefault(i, f"vehicle {i}: the helper refused it: {str(h.get('reason'))[:300]}")
                return self._maybe_accept()
            self._peer[i] = read_vshare(h, blobs, self.params.encoding(self.phase).field)
            return self._decide(i)
        if kind == "result":
            return self._result(h, blobs)
        raise MessageError(f"unknown helper message {kind!r}")

    def _result(self, h: dict, blobs: list[bytes]) -> list[Publish]:
        if self._pending is None or len(blobs) != 3:
            raise MessageError("a result that was not asked for (or not 3 parts)")
        acc, share = self._pending
        k, enc = self.phase, self.params.encoding(self.phase)
        if ids_field(h, "accepted", "result") != acc:
            return self._abort(f"phase {k}: the helper's result is over another set")
        verify_signature(self.peer_cert.public_key, result_bytes(self.session, k, acc, blobs[1]), blobs[2],
                         "the helper's result")
        m = self._next_m((share + elements(enc.field, blobs[0], "helper sum share", enc.length)) % enc.field.p,
                         len(acc))
        if m.astype("<f8").tobytes() != blobs[1]:
            return self._abort(f"phase {k}: the helper's signed result is not the sum of the two shares")
        self._m, self._signed = m, pack({"phase": k, "accepted": list(acc)}, blobs[1], blobs[2])
        if k == 1:
            self.accepted = acc
        if k == self.params.phases:
            self.result = m
            self.state = "finished"
            reason = f"{len(acc)} inputs over {k} phases, refused {sorted(self.refused)}"
            self.events.append(("finished", reason))
            return self._closed("finished", reason)
        self.phase += 1
        self._new_phase()
        vids = {i: v for v, i in self.pid.items()}
        return [self._invite(vids[i]) for i in self.accepted]

    def _closed(self, outcome: str, reason: str) -> list[Publish]:
        return closed_notices(self.topics, self.keys, list(self.pid), outcome, reason, self.accepted, self.phase)

    def _abort(self, reason: str) -> list[Publish]:
        self.state = "aborted"
        self.events.append(("aborted", reason))
        return self._closed("aborted", reason)
