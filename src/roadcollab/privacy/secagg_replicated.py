"""Validated aggregation with replicated shares: three aggregators, any one of which may deviate (issue 20, Sec. 2).

With two aggregators (:mod:`.secagg_validity`) each holds one additive share, so neither can check the
other's sum share: a deviating aggregator chooses the published result, and in phased sessions
(:mod:`.secagg_phased`) that result is the centre every vehicle clips its next deviation around, a
non-linear query on the individual inputs (docs/security-secagg.md, "A deviating aggregator steers the
centres"). Here the input is split into three additive components ``x = x_0 + x_1 + x_2`` (replicated
secret sharing, honest majority; Araki, Furukawa, Lindell, Nof and Ohara, CCS 2016) and aggregator ``a``
holds components ``a`` and ``a + 1 (mod 3)``:

- every component is held by two aggregators, who report its verifier share and its sum identically or
  are caught: one deviating aggregator cannot change a decision or a sum unnoticed (the others abort);
- every aggregator lacks one component, which is uniform to it: one aggregator alone learns nothing of an
  input, and two (colluding) learn everything, as two did before.

Component 0 is sent in full (``x - x_1 - x_2``) to its two holders; components 1 and 2 are expanded from
16-byte seeds. Each component ``j`` is bound by its joint-randomness part
``H(j, blind_j, session, id, data_j)`` (Prio3's parts; the blind is seen by ``j``'s two holders only) and
component 0's proof share by a digest; the vehicle signs the session, its id, the three parts and the
digest. Both holders of ``j`` check ``j``'s part on what they received, so by collision resistance they
hold the same bytes: honest holders compute the same verifier share and the same sum, and a difference
is a deviating aggregator.

The query randomness ``r``, ``s`` of the proofs (which no vehicle may know before its upload is fixed: a
prover that knows ``r`` passes with any input) comes from a coin toss among the aggregators
(:func:`coin_commitment`, :func:`coin_key`): each commits to a random coin before the uploads close and
reveals it after, so one deviating aggregator can neither tell a colluding vehicle ``r`` in advance nor
choose it.

The same code with ``aggregators=2`` is the two-aggregator scheme (``A`` holds component 0, ``B``
component 1), with the coin toss in place of a shared key. Combining every aggregator's reports and the
in-process run: :mod:`.secagg_replicated_run`.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from dataclasses import field as dc_field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import MessageError, ParameterError
from ..wire.certificate import verify_signature
from .secagg_flp import Proof, ValidityEncoding, prove, query
from .secagg_messages import AggregationRefused
from .secagg_validity import _h, _id, query_randomness  # the same length-prefixed hash and id bytes

__all__ = ["holdings", "AggregatorShare", "Commitments", "Upload", "Verification", "ReplicatedAggregator", "submit",
           "signed_bytes", "coin_commitment", "coin_key"]

#: Components held by each aggregator, by the number of aggregators.
_HOLDINGS = {2: ((0,), (1,)), 3: ((0, 1), (1, 2), (2, 0))}


def holdings(aggregators: int) -> tuple[tuple[int, ...], ...]:
    """The components each aggregator holds: ``((0,), (1,))`` for two, ``((0, 1), (1, 2), (2, 0))`` for three.

    Parameters
    ----------
    aggregators : int
        2 or 3.
    """
    if aggregators not in _HOLDINGS:
        raise ParameterError(f"aggregators must be 2 or 3, got {aggregators!r}")
    return _HOLDINGS[aggregators]


def _part(j: int, blind: bytes, session: bytes, vehicle: int, data: bytes) -> bytes:
    return _h(b"rss-part-%d" % j, blind, session, _id(vehicle), data)


def signed_bytes(session: bytes, vehicle: int, parts: Sequence[bytes], proof_digest: bytes) -> bytes:
    """What a vehicle signs: the session, its id, every component's joint-randomness part and the digest of
    component 0's proof share (together they bind every share an aggregator receives).

    Parameters
    ----------
    session : bytes
    vehicle : int
    parts : sequence of bytes
        One per component.
    proof_digest : bytes
    """
    return _h(b"roadcollab-rss-submission", session, _id(vehicle), *parts, proof_digest)


def coin_commitment(session: bytes, party: str, coin: bytes) -> bytes:
    """An aggregator's commitment to its coin of ``session`` (a phase's session bytes).

    Parameters
    ----------
    session : bytes
    party : str
        The aggregator's id.
    coin : bytes
        32 random bytes, revealed after the uploads close.
    """
    return _h(b"roadcollab-rss-coin", session, party.encode(), coin)


def coin_key(session: bytes, coins: Sequence[bytes]) -> bytes:
    """The key of the proofs' query randomness: every aggregator's revealed coin, in aggregator order.

    Parameters
    ----------
    session : bytes
    coins : sequence of bytes
    """
    return _h(b"roadcollab-rss-query-key", session, *coins)


@dataclass(frozen=True)
class AggregatorShare:
    """What one aggregator receives of a vehicle's input (sealed to it on a network).

    Attributes
    ----------
    comps : tuple of int
        The components it holds.
    x0, proof0 : (L + T,) and (proof_length,) object ndarray, or None
        Component 0's shares of the input and the proof, in full (None unless 0 is held).
    seeds : dict
        Component ``j > 0`` held to its 16-byte seed.
    blinds : dict
        Every held component to its 16-byte blind.
    """

    comps: tuple[int, ...]
    x0: np.ndarray | None
    proof0: np.ndarray | None
    seeds: dict[int, bytes]
    blinds: dict[int, bytes]


@dataclass(frozen=True)
class Commitments:
    """What every aggregator sees of a vehicle's upload: the parts, the proof digest and the signature."""

    vehicle: int
    parts: tuple[bytes, ...]
    proof_digest: bytes
    signature: bytes = b""


@dataclass(frozen=True)
class Upload:
    """One vehicle's upload: the public commitments and one share per aggregator."""

    commitments: Commitments
    shares: tuple[AggregatorShare, ...]

    @property
    def vehicle(self) -> int:
        return self.commitments.vehicle


def submit(enc: ValidityEncoding, u: ArrayLike, session: bytes, vehicle: int, rng: np.random.Generator, *,
           aggregators: int = 3, x: np.ndarray | None = None, identity: Any = None) -> Upload:
    """An honest vehicle's upload of ``u`` (inside the box, and the ball if ``enc`` has a norm).

    Parameters
    ----------
    enc : ValidityEncoding
    u : (L,) array_like
    session : bytes
    vehicle : int
    rng : numpy.random.Generator
        Seeds and blinds (a deployment uses the operating system's entropy).
    aggregators : int
        2 or 3.
    x : object ndarray, optional
        A pre-encoded (possibly invalid) ``x`` instead of ``encode(u)``: a cheater's tool in tests.
    identity : VehicleIdentity, optional
        Signs the upload.

    Returns
    -------
    Upload
    """
    f, hold = enc.field, holdings(aggregators)
    x = enc.encode(u) if x is None else x
    seeds = {j: rng.bytes(16) for j in range(1, aggregators)}
    blinds = [rng.bytes(16) for _ in range(aggregators)]
    x0 = x
    for seed in seeds.values():
        x0 = (x0 - f.elements(seed, b"x", x.size)) % f.p
    parts = (_part(0, blinds[0], session, vehicle, f.to_bytes(x0)),) + tuple(
        _part(j, blinds[j], session, vehicle, seeds[j]) for j in range(1, aggregators))
    rho = _rho(enc, parts)
    proof0 = prove(enc, x, rho, f.elements(rng.bytes(16), b"wire-seeds", 2 * enc.chunk)).elements
    for seed in seeds.values():
        proof0 = (proof0 - f.elements(seed, b"proof", proof0.size)) % f.p
    digest = hashlib.sha256(f.to_bytes(proof0)).digest()
    sig = identity.sign(signed_bytes(session, vehicle, parts, digest)) if identity is not None else b""
    shares = tuple(AggregatorShare(comps, x0 if 0 in comps else None, proof0 if 0 in comps else None,
                                   {j: seeds[j] for j in comps if j}, {j: blinds[j] for j in comps})
                   for comps in hold)
    return Upload(Commitments(vehicle, parts, digest, sig), shares)


def _joint(parts: Sequence[bytes]) -> bytes:
    return _h(b"rss-joint", *parts)


def _rho(enc: ValidityEncoding, parts: Sequence[bytes]) -> np.ndarray:
    return enc.field.elements(_joint(parts), b"rho", max(enc.n_rho, 1))[:enc.n_rho]


@dataclass(frozen=True)
class Verification:
    """One aggregator's verifier shares of one vehicle: the joint-randomness seed and one share per held component."""

    vehicle: int
    joint: bytes
    values: dict[int, np.ndarray]


@dataclass
class _Held:
    commitments: Commitments
    comps: dict[int, tuple[np.ndarray, np.ndarray]]      # component -> (x share, proof share)


@dataclass(eq=False)
class ReplicatedAggregator:
    """Aggregator ``index`` of ``aggregators``: checks what it holds of every upload, computes its verifier
    shares once the coins are revealed and releases its components' sums once per session.

    Parameters
    ----------
    enc : ValidityEncoding
    index : int
        0 (the leader), 1 or 2.
    aggregators : int
        2 or 3.
    """

    enc: ValidityEncoding
    index: int
    aggregators: int = 3
    held: dict[int, _Held] = dc_field(default_factory=dict)
    shares: dict[int, dict[int, np.ndarray]] = dc_field(default_factory=dict)
    released: bool = False

    def __post_init__(self) -> None:
        hold = holdings(self.aggregators)
        if not 0 <= self.index < len(hold):
            raise ParameterError(f"index must be in 0..{len(hold) - 1}, got {self.index}")

    @property
    def comps(self) -> tuple[int, ...]:
        """The components this aggregator holds."""
        return holdings(self.aggregators)[self.index]

    def receive(self, commitments: Commitments, share: AggregatorShare, session: bytes, trust: Any = None,
                certificate: Any = None) -> None:
        """Check and keep what this aggregator holds of one vehicle's upload (before the coins are revealed).

        Parameters
        ----------
        commitments : Commitments
            Untrusted.
        share : AggregatorShare
            Untrusted: this aggregator's.
        session : bytes
        trust : FleetTrust, optional
            Check the signature against ``certificate``.
        certificate : Certificate, optional

        Raises
        ------
        MessageError
            Malformed shares, a share that does not open its part or digest, a bad signature, or a second
            upload of the vehicle, naming the vehicle.
        """
        enc, f, i = self.enc, self.enc.field, commitments.vehicle
        n = enc.length + enc.n_bits
        if i in self.held:
            raise MessageError(f"vehicle {i}: a second upload in this session")
        parts = tuple(bytes(p) for p in commitments.parts)
        if len(parts) != self.aggregators or any(len(p) != 32 for p in parts) or len(commitments.proof_digest) != 32:
            raise MessageError(f"vehicle {i}: expected {self.aggregators} joint-randomness parts and a proof digest "
                               "of 32 bytes each")
        if tuple(share.comps) != self.comps or set(share.blinds) != set(self.comps) or \
                set(share.seeds) != {j for j in self.comps if j} or any(len(b) != 16 for b in share.blinds.values()) \
                or any(len(s) != 16 for s in share.seeds.values()):
            raise MessageError(f"vehicle {i}: a share that is not components {list(self.comps)} with 16-byte "
                               "seeds and blinds")
        comps = {}
        for j in self.comps:
            if j == 0:
                x, proof = share.x0, share.proof0
                if x is None or proof is None or np.shape(x) != (n,) or np.shape(proof) != (enc.proof_length,):
                    raise MessageError(f"vehicle {i}: component 0 of the wrong length")
                x, proof = np.asarray(x, dtype=object), np.asarray(proof, dtype=object)
                if any(not 0 <= int(v) < f.p for v in x) or any(not 0 <= int(v) < f.p for v in proof):
                    raise MessageError(f"vehicle {i}: a share element is not in F_p")
                data = f.to_bytes(x)
                if hashlib.sha256(f.to_bytes(proof)).digest() != commitments.proof_digest:
                    raise MessageError(f"vehicle {i}: the proof share does not match its digest")
            else:
                data = share.seeds[j]
                x = f.elements(data, b"x", n)
                proof = f.elements(data, b"proof", enc.proof_length)
            if _part(j, share.blinds[j], session, i, data) != parts[j]:
                raise MessageError(f"vehicle {i}: component {j} does not match its joint-randomness part")
            comps[j] = (x, proof)
        if trust is not None:
            cert = trust.check(certificate)
            verify_signature(cert.public_key, signed_bytes(session, i, parts, commitments.proof_digest),
                             commitments.signature, f"vehicle {i}'s upload")
        self.held[i] = _Held(Commitments(i, parts, bytes(commitments.proof_digest), commitments.signature), comps)

    def verify(self, vehicle: int, session: bytes, key: bytes) -> Verification:
        """This aggregator's verifier shares of ``vehicle`` under the coin-tossed ``key`` (:func:`coin_key`);
        the ``q`` shares are kept for :meth:`component_sums` and the rest is dropped.

        Parameters
        ----------
        vehicle : int
            One whose upload :meth:`receive` kept.
        session : bytes
        key : bytes
        """
        held = self.held[vehicle]
        parts = held.commitments.parts
        jr, rho = _joint(parts), _rho(self.enc, parts)
        r, s = query_randomness(self.enc, key, session, vehicle, jr)
        values = {j: query(self.enc, x, Proof(proof), rho, r, s, j == 0) for j, (x, proof) in held.comps.items()}
        self.shares[vehicle] = {j: x[:self.enc.length] for j, (x, _) in held.comps.items()}
        held.comps = {}
        return Verification(vehicle, jr, values)

    def component_sums(self, accepted: Iterable[int], min_inputs: int = 2) -> dict[int, np.ndarray]:
        """The sums of this aggregator's components' ``q`` shares over ``accepted``: once per session and only
        over at least ``min_inputs`` vehicles it verified.

        Parameters
        ----------
        accepted : iterable of int
        min_inputs : int

        Raises
        ------
        AggregationRefused
            Released before, too few vehicles, or one not verified here.
        """
        accepted = sorted(set(accepted))
        if self.released:
            raise AggregationRefused("this aggregator already released its sums for this session")
        if len(accepted) < min_inputs or any(i not in self.shares for i in accepted):
            raise AggregationRefused(f"sums need at least {min_inputs} vehicles verified by this aggregator")
        self.released = True
        p = self.enc.field.p
        out = {}
        for j in self.comps:
            total = np.zeros(self.enc.length, dtype=object)
            for i in accepted:
                total = (total + self.shares[i][j]) % p
            out[j] = total
        return out
