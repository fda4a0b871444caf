"""Bounded influence inside secure aggregation: two aggregators check every input's validity proof
(issue 20, section 2).

A vehicle sends aggregator ``A`` (the roadside service, the leader) its share of the encoded input and
of the proof of :mod:`.secagg_flp` in full, and aggregator ``B`` (a second aggregator, e.g. the road agency)
a 16-byte seed from which ``B``'s shares are expanded (sealed to ``B`` on a network). Both parts carry
the vehicle's Ed25519 signature over the session, its id and both joint-randomness parts (which bind both
shares). ``A`` and ``B`` derive the query randomness from a key they share, exchange one verifier share
per vehicle, add the ``q`` shares of the accepted vehicles only and combine the two sums: a vehicle whose
proof fails is refused and named, and one whose upload is incomplete is not counted (no dropout recovery
is needed). Threat model and costs: docs/security-secagg.md.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from dataclasses import field as dc_field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._validation import check_int
from ..errors import MessageError, ParameterError
from ..wire.certificate import verify_signature
from .secagg_flp import Field, Proof, ValidityEncoding, decide, prove, query
from .secagg_messages import AggregationRefused

__all__ = ["Submission", "LeaderUpload", "HelperUpload", "VerifierShare", "ValidityAggregator", "submit",
           "signed_bytes", "query_randomness", "ValidatedAggregate", "run_validated_aggregation", "run_validated_session"]



def _h(*parts: bytes) -> bytes:
    m = hashlib.sha256()
    for x in parts:
        m.update(len(x).to_bytes(8, "little") + x)
    return m.digest()


def _id(vehicle: int) -> bytes:
    return int(vehicle).to_bytes(4, "little")


@dataclass(frozen=True)
class LeaderUpload:
    """What aggregator ``A`` receives from a vehicle: its share of ``x`` and of the proof in full."""

    x: np.ndarray
    proof: Proof
    blind: bytes
    peer_part: bytes       # B's joint-randomness part (public share)


@dataclass(frozen=True)
class HelperUpload:
    """What aggregator ``B`` receives (sealed to ``B`` on a network): a 16-byte seed of its shares."""

    seed: bytes
    blind: bytes
    peer_part: bytes       # A's joint-randomness part


@dataclass(frozen=True)
class Submission:
    """One vehicle's upload: both shares, or it is not counted.

    Attributes
    ----------
    vehicle : int
    leader, helper : LeaderUpload, HelperUpload
    signature : bytes
        The vehicle's Ed25519 signature of both parts (empty without identities).
    """

    vehicle: int
    leader: LeaderUpload
    helper: HelperUpload
    signature: bytes = b""

    def nbytes(self, enc: ValidityEncoding) -> tuple[int, int]:
        """Bytes sent to ``A`` and to ``B`` (without transport headers, certificate and signature).

        Parameters
        ----------
        enc : ValidityEncoding
        """
        w = enc.field.nbytes
        a = w * (self.leader.x.size + self.leader.proof.elements.size) + 16 + 32
        return a, 16 + 16 + 32


def _parts(session: bytes, vehicle: int, x_a: np.ndarray, blind_a: bytes, seed: bytes, blind_b: bytes,
           f: Field) -> tuple[bytes, bytes]:
    return (_h(b"part-A", blind_a, session, _id(vehicle), f.to_bytes(x_a)),
            _h(b"part-B", blind_b, session, _id(vehicle), seed))


def _joint(enc: ValidityEncoding, part_a: bytes, part_b: bytes) -> tuple[bytes, np.ndarray]:
    jr = _h(b"joint", part_a, part_b)
    return jr, enc.field.elements(jr, b"rho", max(enc.n_rho, 1))[:enc.n_rho]


def query_randomness(enc: ValidityEncoding, key: bytes, session: bytes, vehicle: int,
                     jr: bytes) -> tuple[int, np.ndarray]:
    """The query point ``r`` (outside the FLP's domain) and the sum check's coefficients ``s`` of one vehicle.

    Parameters
    ----------
    enc : ValidityEncoding
    key : bytes
        Known to the aggregators only (no vehicle may know ``r`` before its upload is fixed).
    session : bytes
    vehicle : int
    jr : bytes
        The vehicle's joint-randomness seed.

    Returns
    -------
    r : int
    s : (L,) object ndarray
    """
    f, P = enc.field, enc.domain
    seed = _h(b"query", key, session, _id(vehicle), jr)
    for k in range(64):
        r = int(f.elements(seed, b"r%d" % k, 1)[0])
        if pow(r, P, f.p) != 1:
            break
    return r, f.elements(seed, b"s", enc.length)


def signed_bytes(session: bytes, vehicle: int, part_a: bytes, part_b: bytes) -> bytes:
    """What a vehicle signs: the session, its id and both joint-randomness parts (they bind both shares).

    Parameters
    ----------
    session : bytes
    vehicle : int
    part_a, part_b : bytes
        Joint-randomness parts.
    """
    return _h(b"roadcollab-prio-submission", session, _id(vehicle), part_a, part_b)


def submit(enc: ValidityEncoding, u: ArrayLike, session: bytes, vehicle: int, rng: np.random.Generator, *,
           x: np.ndarray | None = None, identity: Any = None) -> Submission:
    """An honest vehicle's submission of ``u`` (clipped into the box first by the caller).

    Parameters
    ----------
    enc : ValidityEncoding
    u : (L,) array_like
        Input inside the box.
    session : bytes
    vehicle : int
    rng : numpy.random.Generator
        Source of seeds and blinds (a deployment uses the OS's CSPRNG).
    x : object ndarray, optional
        A pre-encoded (possibly invalid) ``x`` instead of ``encode(u)``: a cheater's tool in tests.
    identity : VehicleIdentity, optional
        Signs the submission.

    Returns
    -------
    Submission
    """
    f = enc.field
    x = enc.encode(u) if x is None else x
    seed, blind_a, blind_b = (rng.bytes(16) for _ in range(3))
    x_b = f.elements(seed, b"x", x.size)
    x_a = (x - x_b) % f.p
    part_a, part_b = _parts(session, vehicle, x_a, blind_a, seed, blind_b, f)
    _, rho = _joint(enc, part_a, part_b)
    seeds = f.elements(rng.bytes(16), b"wire-seeds", 2 * enc.chunk)
    proof = prove(enc, x, rho, seeds).elements
    proof_a = (proof - f.elements(seed, b"proof", proof.size)) % f.p
    sig = identity.sign(signed_bytes(session, vehicle, part_a, part_b)) if identity is not None else b""
    return Submission(vehicle, LeaderUpload(x_a, Proof(proof_a), blind_a, part_b),
                      HelperUpload(seed, blind_b, part_a), sig)


@dataclass(frozen=True)
class VerifierShare:
    """What the two aggregators exchange per vehicle: the joint-randomness seed used and the verifier share."""

    vehicle: int
    joint: bytes
    values: np.ndarray


@dataclass(eq=False)
class ValidityAggregator:
    """Aggregator ``A`` (``leader=True``) or ``B``: checks proofs on its shares and sums the accepted ``q``.

    Parameters
    ----------
    enc : ValidityEncoding
    verify_key : bytes
        Shared by ``A`` and ``B`` only (query randomness ``r``, ``s``).
    leader : bool
    """

    enc: ValidityEncoding
    verify_key: bytes
    leader: bool
    shares: dict[int, np.ndarray] = dc_field(default_factory=dict)
    released: bool = False

    def _share(self, sub: Submission, session: bytes) -> tuple[np.ndarray, Proof, bytes, bytes]:
        f, enc = self.enc.field, self.enc
        if self.leader:
            up = sub.leader
            x, proof = np.asarray(up.x, dtype=object), up.proof
            if x.shape != (enc.length + enc.n_bits,) or proof.elements.shape != (enc.proof_length,):
                raise MessageError(f"vehicle {sub.vehicle}: shares of the wrong length")
            if any(not 0 <= int(v) < f.p for v in x) or any(not 0 <= int(v) < f.p for v in proof.elements):
                raise MessageError(f"vehicle {sub.vehicle}: a share element is not in F_p")
            own = _h(b"part-A", up.blind, session, _id(sub.vehicle), f.to_bytes(x))
            return x, proof, own, up.peer_part
        hp = sub.helper
        if len(hp.seed) != 16:
            raise MessageError(f"vehicle {sub.vehicle}: the helper seed must be 16 bytes")
        x = f.elements(hp.seed, b"x", enc.length + enc.n_bits)
        proof = Proof(f.elements(hp.seed, b"proof", enc.proof_length))
        own = _h(b"part-B", hp.blind, session, _id(sub.vehicle), hp.seed)
        return x, proof, own, hp.peer_part

    def prepare(self, sub: Submission, session: bytes, trust: Any = None, certificate: Any = None) -> VerifierShare:
        """This aggregator's verifier share for ``sub`` (its ``q`` share kept for :meth:`aggregate_share`).

        Parameters
        ----------
        sub : Submission
        session : bytes
        trust : FleetTrust, optional
            Check the signature against ``certificate``.
        certificate : Certificate, optional
            The vehicle's (with ``trust``).

        Raises
        ------
        MessageError
            Malformed shares or a bad signature, naming the vehicle.
        """
        x, proof, own, peer = self._share(sub, session)
        part_a, part_b = (own, peer) if self.leader else (peer, own)
        if trust is not None:
            cert = trust.check(certificate)
            verify_signature(cert.public_key, signed_bytes(session, sub.vehicle, part_a, part_b), sub.signature,
                             f"vehicle {sub.vehicle}'s submission")
        jr, rho = _joint(self.enc, part_a, part_b)
        r, s = self._query_randomness(session, sub.vehicle, jr)
        self.shares[sub.vehicle] = x[:self.enc.length]
        return VerifierShare(sub.vehicle, jr, query(self.enc, x, proof, rho, r, s, self.leader))

    def _query_randomness(self, session: bytes, vehicle: int, jr: bytes) -> tuple[int, np.ndarray]:
        return query_randomness(self.enc, self.verify_key, session, vehicle, jr)

    def check(self, own: VerifierShare, other: VerifierShare) -> str:
        """``""`` if the vehicle's input is valid, else why not (both aggregators reach the same answer).

        Parameters
        ----------
        own : VerifierShare
            This aggregator's.
        other : VerifierShare
            The peer's (untrusted).
        """
        if own.vehicle != other.vehicle:
            raise MessageError("verifier shares of two different vehicles")
        if own.joint != other.joint:
            return "its two shares give different joint randomness"
        if np.asarray(other.values).shape != own.values.shape:
            return "the peer's verifier share has the wrong length"
        return decide(self.enc, (own.values + np.asarray(other.values, dtype=object)) % self.enc.field.p)

    def aggregate_share(self, accepted: Iterable[int], min_inputs: int = 2) -> np.ndarray:
        """The sum of this aggregator's ``q`` shares over ``accepted``, (L,) object ndarray: once per session
        (two sums over sets that differ by one vehicle would give that vehicle's input away) and only over
        at least ``min_inputs`` vehicles whose proof this aggregator checked. In memory only (not persisted).

        Parameters
        ----------
        accepted : iterable of int
            Vehicles whose proofs checked.
        min_inputs : int
            ``k``.

        Raises
        ------
        AggregationRefused
            A sum was already released, fewer than ``min_inputs`` vehicles, or one not checked here.
        """
        accepted = sorted(set(accepted))
        if self.released:
            raise AggregationRefused("this aggregator already released its sum share for this session")
        if len(accepted) < min_inputs or any(i not in self.shares for i in accepted):
            raise AggregationRefused(f"a sum share needs at least {min_inputs} vehicles whose proofs were checked")
        self.released = True
        total = np.zeros(self.enc.length, dtype=object)
        for i in accepted:
            total = (total + self.shares[i]) % self.enc.field.p
        return total


@dataclass(frozen=True)
class ValidatedAggregate:
    """The outcome of one validated aggregation.

    Attributes
    ----------
    total : (L,) ndarray or None
        ``sum u`` over the accepted vehicles (None: fewer than ``min_inputs`` accepted).
    accepted : tuple of int
    refused : dict
        Vehicle id to the reason its input was refused.
    """

    total: np.ndarray | None
    accepted: tuple[int, ...]
    refused: dict[int, str]

    @property
    def average(self) -> np.ndarray | None:
        """``total / |accepted|``."""
        return None if self.total is None else self.total / len(self.accepted)


def run_validated_aggregation(enc: ValidityEncoding, submissions: dict[int, Submission], session: bytes, *, verify_key: bytes,
                              min_inputs: int = 2, trust: Any = None,
                              certificates: dict[int, Any] | None = None) -> ValidatedAggregate:
    """Both aggregators in-process: verify every submission on the shares, exchange verifier shares, sum
    the accepted ``q`` shares and combine them (the only values ``A`` and ``B`` reveal to each other).

    Parameters
    ----------
    enc : ValidityEncoding
    submissions : dict
        Vehicle id to :class:`Submission`; a vehicle whose submission is missing is not counted.
    session : bytes
        ``session_id(segment, epoch)``.
    verify_key : bytes
        The aggregators' shared key.
    min_inputs : int
        ``k``: no sum of fewer accepted inputs is revealed.
    trust : FleetTrust, optional
        Check every submission's signature against its certificate.
    certificates : dict, optional
        Vehicle id to its certificate (with ``trust``).

    Returns
    -------
    ValidatedAggregate
    """
    a = ValidityAggregator(enc, verify_key, True)
    b = ValidityAggregator(enc, verify_key, False)
    if len(submissions) > enc.max_fleet():
        raise ParameterError(f"at most {enc.max_fleet()} inputs fit the field, got {len(submissions)}")
    accepted, refused = [], {}
    for i, sub in sorted(submissions.items()):
        try:
            if sub.vehicle != i:
                raise MessageError(f"vehicle {i}: the submission names vehicle {sub.vehicle}")
            cert = None if certificates is None else certificates[i]
            va, vb = a.prepare(sub, session, trust, cert), b.prepare(sub, session, trust, cert)
        except MessageError as e:
            refused[i] = str(e)
            continue
        why_a, why_b = a.check(va, vb), b.check(vb, va)
        if why_a or why_b:
            refused[i] = f"vehicle {i}: {why_a or why_b}"
        else:
            accepted.append(i)
    if len(accepted) < check_int("min_inputs", min_inputs, low=1):
        return ValidatedAggregate(None, tuple(accepted), refused)
    q = (a.aggregate_share(accepted, min_inputs) + b.aggregate_share(accepted, min_inputs)) % enc.field.p
    return ValidatedAggregate(enc.decode_sum(q, len(accepted)), tuple(accepted), refused)


def run_validated_session(fleet: Any, inputs: dict[int, ArrayLike], session: bytes, enc: ValidityEncoding, *, verify_key: bytes,
                          rng: Any = None,
                          tamper: Callable[[int, Submission], Submission] | None = None) -> ValidatedAggregate:
    """A validated aggregation among the certified vehicles of ``fleet`` (:class:`~.secagg_active_run.SecAggFleet`).

    Each vehicle clips its input into the public box, records in its ledger that its input of ``session``
    (segment, epoch) is sent (a second session on the same measurement is refused, as in the active
    protocol), signs and submits. The aggregators check certificates, signatures and proofs, and reveal
    the sum only if at least ``fleet.spec.min_inputs`` inputs are valid.

    Parameters
    ----------
    fleet : SecAggFleet
    inputs : dict
        Vehicle id to its input, (L,) or any shape of ``L`` values.
    session : bytes
    enc : ValidityEncoding
    verify_key : bytes
    rng : int or numpy.random.Generator, optional
    tamper : callable, optional
        ``tamper(vehicle, submission) -> submission``: a malicious vehicle's change to what it sends.

    Returns
    -------
    ValidatedAggregate
    """
    gen = np.random.default_rng(rng)
    subs, refused = {}, {}
    for i, z in sorted(inputs.items()):
        v = fleet.vehicles[i]
        try:
            v.ledger.record_contribution(session, sorted(inputs))
        except AggregationRefused as e:
            refused[i] = f"vehicle {i} sends nothing: {e}"
            continue
        u, _ = enc.clip(np.asarray(z, float).ravel())
        sub = submit(enc, u, session, i, gen, identity=v.identity)
        subs[i] = sub if tamper is None else tamper(i, sub)
    certs = {i: fleet.vehicles[i].identity.certificate for i in subs}
    out = run_validated_aggregation(enc, subs, session, verify_key=verify_key, min_inputs=fleet.spec.min_inputs,
                                    trust=fleet.trust, certificates=certs)
    return ValidatedAggregate(out.total, out.accepted, {**refused, **out.refused})
