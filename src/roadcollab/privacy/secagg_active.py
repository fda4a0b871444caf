"""Secure aggregation against an active aggregator and malicious vehicles (Bonawitz et al. 2017, active variant).

The semi-honest protocol of :mod:`.secure_aggregation` trusts the aggregator to relay honestly. Here every
vehicle is a state machine (:class:`SecAggVehicle`, no I/O: a transport hands it messages and sends what it
returns) that checks what the aggregator relays:

- **Certified rosters** (round 0): each key advert is signed by the vehicle's fleet identity
  (:func:`~roadcollab.wire.secagg_signed.sign_advert`). A roster is accepted only if every advert verifies
  against the fleet's trust anchor, no certificate appears twice, it holds the vehicle's own advert
  unchanged and ``k <= n <= 2t - c - 1`` (:attr:`SecAggSpec.max_roster`). Invented ids (Sybil) and
  substituted keys fail the signature.
- **Committed shares** (round 1): the dealer signs ``H`` of every share it deals and of its ``b``
  (:class:`~roadcollab.wire.secagg_signed.ShareCommitments`). A holder checks what it opens; the aggregator
  checks every revealed share, excludes a wrong one and names its holder (:func:`unmask_verified`), and
  checks a reconstructed ``b`` (or ``s_sk``, against ``s_pk``), naming a dealer whose shares disagree.
- **One input per segment and epoch** (round 2): the vehicle records the contribution in its
  :class:`~.secagg_store.SessionLedger` *before* sending ``y``; a second session of the same measurement
  (segment, epoch) is refused, so differencing two aggregates has nothing to subtract.
- **Consistency round** (round 2.5) and **stateful unmasking** (round 3): a vehicle signs one survivor set
  ``U_3`` per session, only if it is itself in it (persisted in the ledger), and reveals only with ``t``
  valid signatures of members of ``U_3`` on that same set: ``b`` shares for ``U_3``, ``s`` shares for the
  rest, never both for one vehicle, in any number of calls or restarts.

Threat model and which ``c`` each claim holds for: ``docs/security-secagg.md``. With ``2t > n + c``, an
aggregator that shows different survivor sets to different vehicles needs two groups of at least ``t - c``
honest vehicles each, which ``n - c`` honest vehicles cannot supply.

References
----------
K. Bonawitz et al., "Practical Secure Aggregation for Privacy-Preserving Machine Learning", ACM CCS 2017,
Fig. 4 (ConsistencyCheck round, signatures) and Thm. 6.5 (active adversary).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import check_int
from ..errors import MessageError, ParameterError
from ..wire.identity import FleetTrust, VehicleIdentity
from ..wire.secagg_signed import (ShareCommitments, open_advert, open_commitments, open_view, secret_hash,
                                  share_hash, sign_advert, sign_commitments, sign_view)
from ._secagg_kernels import KEY_NBYTES, decode_sum, derive, prg_ring, shamir_combine, shamir_split, x25519_keypair
from .secagg_messages import (AggregateResult, AggregationRefused, KeyAdvert, MaskedInput, Reveal, SecAggSpec,
                              VehicleSecrets)
from .secagg_store import SessionLedger, view_digest
from .secure_aggregation import _collect, _open_share, _pair_mask, advertise_keys, mask_input, share_keys

__all__ = ["VerifiedRoster", "verify_roster", "SecAggVehicle", "VerifiedAggregate", "unmask_verified"]


@dataclass(frozen=True)
class VerifiedRoster:
    """``U_1`` after every signed advert was checked.

    Attributes
    ----------
    session : bytes
    adverts : dict of int to KeyAdvert
        Protocol id -> its advert (keys bound to the certificate).
    certificates : dict of int to str
        Protocol id -> the certified vehicle id (each at most once).
    """

    session: bytes
    adverts: dict[int, KeyAdvert]
    certificates: dict[int, str]

    @property
    def ids(self) -> list[int]:
        """Sorted protocol ids."""
        return sorted(self.adverts)


def verify_roster(signed: dict[int, bytes], trust: FleetTrust, session: bytes, spec: SecAggSpec) -> VerifiedRoster:
    """Check a roster of signed adverts (as relayed, untrusted) for ``session``.

    Parameters
    ----------
    signed : dict of int to bytes
        Protocol id -> signed advert envelope.
    trust : FleetTrust
    session : bytes
    spec : SecAggSpec

    Returns
    -------
    VerifiedRoster

    Raises
    ------
    MessageError
        An advert that does not verify (uncertified, revoked, forged, another session), an id that does
        not match its advert, or a certificate used twice.
    AggregationRefused
        Fewer than ``k`` or more than ``2t - c - 1`` vehicles.
    """
    if not isinstance(signed, dict) or not signed:
        raise MessageError("roster must map vehicle ids to signed adverts")
    adverts: dict[int, KeyAdvert] = {}
    certs: dict[int, str] = {}
    for i, data in signed.items():
        cert, advert = open_advert(data, trust, session)
        if advert.vehicle != i:
            raise MessageError(f"roster entry {i} carries the advert of vehicle {advert.vehicle}")
        adverts[i], certs[i] = advert, cert.vehicle_id
    if len(set(certs.values())) != len(certs):
        raise MessageError("roster lists one certified vehicle under two ids (Sybil)")
    n = len(adverts)
    if n < spec.min_inputs:
        raise AggregationRefused(f"roster has {n} certified vehicles, at least k = {spec.min_inputs} required")
    if n > spec.max_roster:
        raise AggregationRefused(f"roster has {n} vehicles; with t = {spec.threshold} and c = {spec.max_colluders} "
                                 f"at most 2t - c - 1 = {spec.max_roster} are safe against equivocation")
    spec.check_fleet(n)
    return VerifiedRoster(session, adverts, certs)


def _commitments(session: bytes, vehicle: int, ids: Iterable[int], s_sh: dict[int, int], b_sh: dict[int, int],
                 b_seed: bytes) -> ShareCommitments:
    return ShareCommitments(vehicle, secret_hash(session, vehicle, b_seed),
                            {j: (share_hash(session, vehicle, j, b"s", s_sh[j]),
                                 share_hash(session, vehicle, j, b"b", b_sh[j])) for j in ids})


class SecAggVehicle:
    """One vehicle's party in the active protocol: checks everything relayed, keeps per-session state.

    Parameters
    ----------
    vehicle : int
        Protocol id (>= 1), the Shamir evaluation point of the shares it holds.
    identity : VehicleIdentity
        Its fleet identity (signs adverts, commitments and the consistency signature).
    trust : FleetTrust
        The fleet's trust anchor (checks every other party).
    spec : SecAggSpec
    ledger : SessionLedger
        Persistent: one input per (segment, epoch), one signed survivor set per session.

    Notes
    -----
    Secrets live in memory only; a vehicle restarted after sending ``y`` cannot reveal for that session
    (safe: the aggregate is lost, nothing is exposed), and its ledger still refuses a second input or
    another survivor set.
    """

    def __init__(self, vehicle: int, identity: VehicleIdentity, trust: FleetTrust, spec: SecAggSpec,
                 ledger: SessionLedger) -> None:
        self.vehicle = check_int("vehicle", vehicle, low=1, high=2 ** 32 - 1)
        if not isinstance(identity, VehicleIdentity) or not isinstance(trust, FleetTrust):
            raise ParameterError("identity must be a VehicleIdentity and trust a FleetTrust")
        if not isinstance(ledger, SessionLedger):
            raise ParameterError(f"ledger must be a SessionLedger, got {type(ledger).__name__}")
        self.identity, self.trust, self.spec, self.ledger = identity, trust, spec, ledger
        self._secrets: VehicleSecrets | None = None
        self._advert: KeyAdvert | None = None
        self._roster: VerifiedRoster | None = None
        self._view: tuple[int, ...] | None = None
        self.complaints: list[tuple[int, str]] = []

    @property
    def session(self) -> bytes:
        """The session of the current attempt (after :meth:`advertise`)."""
        return self._sec.session

    @property
    def _sec(self) -> VehicleSecrets:
        if self._secrets is None:
            raise ParameterError("advertise() first")
        return self._secrets

    @property
    def _ros(self) -> VerifiedRoster:
        if self._roster is None:
            raise ParameterError("share_keys() first")
        return self._roster

    def advertise(self, session: bytes, *, root: bytes | None = None) -> bytes:
        """Round 0: fresh keys for ``session``, as a signed advert.

        Parameters
        ----------
        session : bytes
            ``session_id(segment, epoch)`` of the measurement to aggregate.
        root : bytes, optional
            32 bytes of every session secret (see :func:`advertise_keys`); default :func:`os.urandom`.

        Returns
        -------
        bytes
            The signed advert envelope.
        """
        self._secrets, self._advert = advertise_keys(self.vehicle, session, root=root or os.urandom(KEY_NBYTES))
        self._roster = self._view = None
        return sign_advert(self.identity, self._advert)

    def share_keys(self, signed_roster: dict[int, bytes]) -> tuple[dict[int, bytes], bytes]:
        """Round 1: check the roster; sealed shares per recipient and the signed share commitments.

        Parameters
        ----------
        signed_roster : dict of int to bytes
            ``U_1`` as relayed (untrusted): protocol id -> signed advert.

        Returns
        -------
        sealed : dict of int to bytes
            Recipient -> sealed shares.
        commitments : bytes
            The signed :class:`~roadcollab.wire.secagg_signed.ShareCommitments`.
        """
        roster = verify_roster(signed_roster, self.trust, self.session, self.spec)
        if roster.adverts.get(self.vehicle) != self._advert:
            raise MessageError(f"roster does not carry vehicle {self.vehicle}'s own advert")
        if roster.certificates[self.vehicle] != self.identity.vehicle_id:
            raise MessageError(f"roster binds id {self.vehicle} to another certificate")
        self._roster = roster
        sec, ids = self._sec, roster.ids
        sealed = share_keys(sec, roster.adverts, self.spec)
        s_sh, b_sh = self._own_polys(ids)
        com = _commitments(sec.session, self.vehicle, ids, s_sh, b_sh, sec.b_seed)
        return sealed, sign_commitments(self.identity, sec.session, com)

    def _own_polys(self, ids: list[int]) -> tuple[dict[int, int], dict[int, int]]:
        sec, t = self._sec, self.spec.threshold
        return (shamir_split(sec.s_sk, ids, t, derive(sec.share_seed, b"s", sec.session)),
                shamir_split(sec.b_seed, ids, t, derive(sec.share_seed, b"b", sec.session)))

    def mask_input(self, z: ArrayLike, measured: tuple[int, int]) -> MaskedInput:
        """Round 2: ``y`` of the measurement ``measured = (segment, epoch)``, which must be this session's.

        Parameters
        ----------
        z : (L, 2) array_like
            The vehicle's inversion of that measurement, m/s.
        measured : (int, int)
            Its segment and epoch, as the vehicle knows them (not as the aggregator claims).

        Returns
        -------
        MaskedInput

        Raises
        ------
        AggregationRefused
            This measurement was already contributed (in this or another session attempt).
        """
        if self._roster is None:
            raise ParameterError("share_keys() first")
        from_session = tuple(int.from_bytes(self.session[k:k + 8], "little") for k in (0, 8))
        if tuple(measured) != from_session:
            raise AggregationRefused(f"session is for (segment, epoch) {from_session}, the input is of {measured}")
        self.ledger.record_contribution(self.session, self._roster.ids)  # written before y leaves
        return mask_input(self._sec, z, self._roster.adverts, self.spec)

    def sign_survivors(self, survivors: Iterable[int]) -> bytes:
        """Round 2.5: the consistency signature on the announced ``U_3`` (one set per session, persisted).

        Parameters
        ----------
        survivors : iterable of int
            ``U_3`` as announced to this vehicle (untrusted).

        Returns
        -------
        bytes
            The signed view envelope.
        """
        if self._roster is None:
            raise ParameterError("share_keys() first")
        view = sorted({int(i) for i in survivors})
        if not set(view) <= set(self._roster.ids):
            raise MessageError(f"announced survivors {sorted(set(view) - set(self._roster.ids))} not in the roster")
        if self.vehicle not in view:
            raise AggregationRefused(f"vehicle {self.vehicle} is not in the announced survivors: it does not reveal")
        if len(view) < self.spec.min_inputs:
            raise AggregationRefused(f"{len(view)} survivors announced, at least k = {self.spec.min_inputs} required")
        self.ledger.record_view(self.session, view)
        self._view = tuple(view)
        return sign_view(self.identity, self.session, self.vehicle, view)

    def _check_signatures(self, signatures: dict[int, bytes], view: tuple[int, ...]) -> None:
        good: set[int] = set()
        for i, data in signatures.items():
            try:
                cert, signer, ids = open_view(data, self.trust, self.session)
            except MessageError:
                continue
            if signer == i and i in view and ids == view and self._ros.certificates[i] == cert.vehicle_id:
                good.add(i)
        if len(good) < self.spec.threshold:
            raise AggregationRefused(f"{len(good)} valid consistency signatures on this survivor set, "
                                     f"t = {self.spec.threshold} required")

    def _dealt(self, dealer: int, blob: object, commitments: dict[int, bytes]) -> tuple[int, int] | None:
        """The (s, b) shares ``dealer`` sealed here if they match its signed commitments, else None (noted)."""
        try:
            s, b = _open_share(self._sec, dealer, blob, self._ros.adverts)
            cert, com = open_commitments(commitments[dealer], self.trust, self.session)
        except (MessageError, KeyError) as err:
            self.complaints.append((dealer, f"no valid sealed share or commitments ({err})"))
            return None
        hs, hb = com.shares.get(self.vehicle, (b"", b""))
        if cert.vehicle_id != self._ros.certificates[dealer] or com.dealer != dealer or \
                hs != share_hash(self.session, dealer, self.vehicle, b"s", s) or \
                hb != share_hash(self.session, dealer, self.vehicle, b"b", b):
            self.complaints.append((dealer, "sealed share does not match the dealer's signed commitment"))
            return None
        return s, b

    def reveal(self, sealed: dict[int, bytes], commitments: dict[int, bytes], signatures: dict[int, bytes]) -> Reveal:
        """Round 3: shares of ``b`` for the signed ``U_3`` and of ``s_sk`` for the rest of the roster.

        Parameters
        ----------
        sealed : dict of int to bytes
            Dealer id -> ciphertext it sealed for this vehicle (forwarded, untrusted).
        commitments : dict of int to bytes
            Dealer id -> its signed commitments (forwarded, untrusted).
        signatures : dict of int to bytes
            Signer id -> consistency signature (forwarded, untrusted); ``t`` valid ones on the signed set.

        Returns
        -------
        Reveal
            Dealers whose sealed share fails its commitment are left out (see :attr:`complaints`).
        """
        view = self._view
        if view is None:
            raise AggregationRefused("no survivor set signed in this session: nothing is revealed")
        if self.ledger.signed_view(self.session) != view_digest(view):
            raise AggregationRefused("the ledger holds another survivor set for this session")
        self._check_signatures(signatures, view)
        ids = self._ros.ids
        s_own, b_own = (p[self.vehicle] for p in self._own_polys(ids))
        b: dict[int, int] = {}
        s: dict[int, int] = {}
        for i in ids:
            sh = (s_own, b_own) if i == self.vehicle else self._dealt(i, sealed.get(i), commitments)
            if sh is not None:
                (b if i in view else s)[i] = sh[1] if i in view else sh[0]
        return Reveal(self.vehicle, b, s, session=self.session)


@dataclass(frozen=True)
class VerifiedAggregate:
    """The aggregate and the revealed shares that failed their commitments (excluded).

    Attributes
    ----------
    result : AggregateResult
    bad_shares : tuple of (int, int)
        ``(holder, owner)`` of every excluded share.
    """

    result: AggregateResult
    bad_shares: tuple[tuple[int, int], ...]


def _good_shares(reveals: Iterable[Reveal], field: str, kind: bytes, owner: int, com: ShareCommitments,
                 session: bytes, bad: list[tuple[int, int]]) -> dict[int, int]:
    got = _collect(reveals, field, owner)
    good: dict[int, int] = {}
    for h, y in got.items():
        if share_hash(session, owner, h, kind, y) == com.shares.get(h, (b"", b""))[kind == b"b"]:
            good[h] = y
        else:
            bad.append((h, owner))
    return good


def unmask_verified(roster: VerifiedRoster, commitments: dict[int, bytes], masked: Iterable[MaskedInput],
                    reveals: Iterable[Reveal], spec: SecAggSpec, trust: FleetTrust) -> VerifiedAggregate:
    """The aggregator's last step with verifiable shares: bad shares excluded, a bad dealer named.

    Parameters
    ----------
    roster : VerifiedRoster
    commitments : dict of int to bytes
        Dealer id -> signed :class:`~roadcollab.wire.secagg_signed.ShareCommitments`.
    masked : iterable of MaskedInput
    reveals : iterable of Reveal
    spec : SecAggSpec
    trust : FleetTrust

    Returns
    -------
    VerifiedAggregate

    Raises
    ------
    AggregationRefused
        Fewer than ``k`` inputs, or fewer than ``t`` valid shares of a secret (the holders of the bad
        ones are named).
    MessageError
        A dealer's valid shares reconstruct a secret that does not match its commitment or key (the
        dealer is named), or inputs outside the roster / of another shape.
    """
    session = roster.session
    by_vehicle = {m.vehicle: m for m in masked}
    answers = [r for r in reveals if r.session == session]
    u2 = sorted(by_vehicle)
    if len(u2) < spec.min_inputs:
        raise AggregationRefused(f"{len(u2)} masked inputs, at least k = {spec.min_inputs} required")
    if not set(u2) <= set(roster.ids) or any(m.session != session for m in by_vehicle.values()):
        raise MessageError("masked inputs from outside the roster or another session")
    shape = by_vehicle[u2[0]].y.shape
    if any(m.y.shape != shape for m in by_vehicle.values()):
        raise MessageError("masked inputs have different shapes")
    coms: dict[int, ShareCommitments] = {}
    for i in roster.ids:
        cert, com = open_commitments(commitments[i], trust, session)
        if cert.vehicle_id != roster.certificates[i] or com.dealer != i:
            raise MessageError(f"commitments of vehicle {i} are signed by another vehicle")
        coms[i] = com
    bad: list[tuple[int, int]] = []

    def secret(owner: int, field: str, kind: bytes) -> bytes:
        good = _good_shares(answers, field, kind, owner, coms[owner], session, bad)
        if len(good) < spec.threshold:
            culprits = sorted({h for h, o in bad if o == owner})
            raise AggregationRefused(f"{len(good)} valid shares of vehicle {owner}'s secret, t = {spec.threshold} "
                                     f"required (wrong shares from vehicles {culprits})")
        try:
            return shamir_combine(good, spec.threshold, f"secret of vehicle {owner}")
        except MessageError as err:   # every share matches its commitment: the dealer dealt them off one polynomial
            raise MessageError(f"vehicle {owner} dealt inconsistent shares ({err})") from None

    total = np.zeros(shape, dtype=np.uint64)
    for i in u2:
        b_i = secret(i, "self_mask_shares", b"b")
        if secret_hash(session, i, b_i) != coms[i].b_hash:
            raise MessageError(f"vehicle {i} dealt shares that do not reconstruct its committed b")
        total += by_vehicle[i].y
        total -= prg_ring(derive(b_i, b"self", session, i), shape)
    dropped = tuple(i for i in roster.ids if i not in by_vehicle)
    for d in dropped:
        s_sk = secret(d, "key_shares", b"s")
        if x25519_keypair(s_sk)[1] != roster.adverts[d].s_pk:
            raise MessageError(f"vehicle {d} dealt shares that do not reconstruct its advertised key")
        for j in u2:
            total -= _pair_mask(s_sk, j, d, roster.adverts[j].s_pk, session, shape)
    return VerifiedAggregate(AggregateResult(decode_sum(total, spec.frac_bits), tuple(u2), dropped), tuple(bad))
