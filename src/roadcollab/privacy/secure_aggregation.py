"""Secure aggregation of the vehicles' inversions (Bonawitz et al. 2017): the aggregator learns a sum only.

The fused estimate of a segment is the average of the vehicles' band-limited inversions ``z_i``
((nfft, 2) arrays, m/s). A roadside unit that is honest but curious collects them; with this protocol
it learns ``sum_i z_i`` over at least ``k`` surviving vehicles and nothing about any single ``z_i``.

Protocol (one session = one segment and round; vehicle ids ``1..n``; 4 rounds through the aggregator):

0. **Advertise keys**: vehicle ``i`` sends two X25519 public keys, ``c_i`` (to seal shares) and ``s_i``
   (pairwise mask seeds). The aggregator broadcasts the roster ``U_1``.
1. **Share keys**: ``i`` Shamir-shares (threshold ``t``) its private ``s_i`` and a self-mask seed ``b_i``
   among ``U_1`` (itself included) and seals each share for ``j`` with ChaCha20-Poly1305 under
   ``HKDF(X25519(c_i, c_j))``; the aggregator forwards ciphertexts it cannot read.
2. **Masked input**: with ``x_i = round(clip(z_i) 2^f) mod 2^64`` and
   ``s_ij = HKDF(X25519(s_i, s_j), session, min(i,j), max(i,j))``

   .. math:: y_i = x_i + \\mathrm{PRG}(b_i) + \\sum_{j > i} \\mathrm{PRG}(s_{ij})
             - \\sum_{j < i} \\mathrm{PRG}(s_{ij}) \\pmod{2^{64}}

   The vehicles that send ``y_i`` form ``U_2``.
3. **Unmasking**: the aggregator announces ``U_2``; each responding vehicle reveals, for every other
   ``i``, its share of ``b_i`` if ``i`` is in ``U_2`` and of ``s_i`` otherwise, never both. With ``t``
   responses the aggregator removes the self masks of ``U_2`` and the pairwise masks that dropped
   vehicles left in the others' ``y``: ``sum_{U_2} y_i - ... = sum_{U_2} x_i``.

What it protects against: an honest-but-curious aggregator colluding with fewer than ``t`` vehicles learns
only the sum over ``U_2`` (so, minus its colluders' own inputs, the sum of ``>= k - c`` honest vehicles);
a masked ``y_i`` is uniform on the ring. The self mask keeps an input that arrives after its sender was
declared dropped (so ``s_i`` was reconstructed) masked. Honest vehicles and the aggregator refuse to
unmask fewer than ``k`` inputs (:class:`AggregationRefused`). Not covered here: an actively malicious
aggregator (differencing two sessions, equivocating about ``U_2``, Sybil rosters, substituted keys) and
wrong shares from malicious vehicles; :mod:`.secagg_active` builds the active protocol on these functions
(signed adverts, share commitments, consistency round, a persistent per-vehicle ledger). Neither bounds a
malicious vehicle's input: ``clip`` is applied by honest vehicles only.

References
----------
K. Bonawitz et al., "Practical Secure Aggregation for Privacy-Preserving Machine Learning", ACM CCS 2017,
Fig. 4 (semi-honest protocol) and Thm. 6.3.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from cryptography.exceptions import InvalidTag
from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305

from .._validation import check_int
from ..errors import MessageError, ParameterError
from ..wire.layout import SEALED_NBYTES
from ._secagg_kernels import (KEY_NBYTES, SHARE_NBYTES, decode_sum, derive, encode_fixed, prg_ring, shamir_combine,
                              shamir_split, x25519_agree, x25519_keypair)
from .secagg_messages import (AggregateResult, AggregationRefused, KeyAdvert, MaskedInput, Reveal, SealedShares,
                              SecAggSpec, VehicleSecrets, session_id)

__all__ = ["AggregationRefused", "SecAggSpec", "session_id", "VehicleSecrets", "KeyAdvert", "SealedShares", "MaskedInput",
           "Reveal", "AggregateResult", "advertise_keys", "share_keys", "mask_input", "reveal_shares", "unmask"]

_PAIR = struct.Struct("<II")
_SEALED_NBYTES = SEALED_NBYTES   # ids, two shares, Poly1305 tag: 156 (wire.layout)
_NONCE = bytes(12)   # every sealing key (per session, sender, recipient) seals exactly one message



def advertise_keys(vehicle: int, session: bytes, *, root: bytes | None = None) -> tuple[VehicleSecrets, KeyAdvert]:
    """Round 0: a vehicle's fresh per-session secrets and the public keys it advertises.

    Parameters
    ----------
    vehicle : int
        Id (>= 1).
    session : bytes
        From :func:`session_id`.
    root : bytes, optional
        32 bytes from which every secret is derived with HKDF; default :func:`os.urandom`. A fixed
        ``root`` makes tests reproducible and must never be used twice in deployment.

    Returns
    -------
    (VehicleSecrets, KeyAdvert)
    """
    vehicle = check_int("vehicle", vehicle, low=1, high=2 ** 32 - 1)
    if not isinstance(session, bytes) or len(session) != len(session_id(0, 0)):
        raise ParameterError(f"session must be the 16 bytes of session_id(segment, round), got {session!r:.40}")
    root = os.urandom(KEY_NBYTES) if root is None else root
    if not isinstance(root, bytes) or len(root) != KEY_NBYTES:
        raise ParameterError(f"root must be {KEY_NBYTES} bytes, got {root!r:.40}")
    keys = {p: derive(root, p, session, vehicle) for p in (b"c_sk", b"s_sk", b"b", b"shamir")}
    c_sk, c_pk = x25519_keypair(keys[b"c_sk"])
    s_sk, s_pk = x25519_keypair(keys[b"s_sk"])
    secrets = VehicleSecrets(vehicle, session, c_sk, s_sk, keys[b"b"], keys[b"shamir"])
    return secrets, KeyAdvert(vehicle, c_pk, s_pk, session=session)


def _check_roster(roster: dict[int, KeyAdvert], spec: SecAggSpec, secrets: VehicleSecrets) -> list[int]:
    """Sorted ids of the roster ``U_1`` (untrusted broadcast); refused if it is smaller than ``k``."""
    if not isinstance(roster, dict) or not all(isinstance(a, KeyAdvert) and a.vehicle == i for i, a in roster.items()):
        raise MessageError("roster must map each vehicle id to its KeyAdvert")
    _check_session(roster.values(), secrets.session)
    vehicle = secrets.vehicle
    if vehicle not in roster:
        raise MessageError(f"roster does not contain vehicle {vehicle}")
    if len(roster) < spec.min_inputs:
        raise AggregationRefused(f"roster has {len(roster)} vehicles, at least k = {spec.min_inputs} required")
    spec.check_fleet(len(roster))
    return sorted(roster)


def _check_session(messages: Iterable[Any], session: bytes) -> None:
    """MessageError if one of ``messages`` (untrusted) belongs to another session (segment, round)."""
    for m in messages:
        if m.session != session:
            raise MessageError(f"{type(m).__name__} of vehicle {m.vehicle} belongs to another session")


def _seal_key(secrets: VehicleSecrets, peer_pk: bytes, sender: int, recipient: int) -> bytes:
    """ChaCha20-Poly1305 key of the sealed shares ``sender -> recipient`` (one per direction and session)."""
    peer = sender if recipient == secrets.vehicle else recipient
    shared = x25519_agree(secrets.c_sk, peer_pk, f"c_pk of vehicle {peer}")
    return derive(shared, b"seal", secrets.session, sender, recipient)


def share_keys(secrets: VehicleSecrets, roster: dict[int, KeyAdvert], spec: SecAggSpec) -> dict[int, bytes]:
    """Round 1: Shamir shares of ``s_sk`` and ``b_seed``, sealed for each other vehicle of ``roster``.

    Parameters
    ----------
    secrets : VehicleSecrets
        This vehicle's, from :func:`advertise_keys`.
    roster : dict of int to KeyAdvert
        ``U_1`` as broadcast by the aggregator.
    spec : SecAggSpec

    Returns
    -------
    dict of int to bytes
        Recipient id -> sealed shares (156 bytes); the vehicle keeps its own shares in ``secrets``.
    """
    ids = _check_roster(roster, spec, secrets)
    s_sh = shamir_split(secrets.s_sk, ids, spec.threshold, derive(secrets.share_seed, b"s", secrets.session))
    b_sh = shamir_split(secrets.b_seed, ids, spec.threshold, derive(secrets.share_seed, b"b", secrets.session))
    out = {}
    for j in ids:
        if j == secrets.vehicle:
            continue
        plain = _PAIR.pack(secrets.vehicle, j) + s_sh[j].to_bytes(SHARE_NBYTES, "little") \
            + b_sh[j].to_bytes(SHARE_NBYTES, "little")
        key = _seal_key(secrets, roster[j].c_pk, secrets.vehicle, j)
        out[j] = ChaCha20Poly1305(key).encrypt(_NONCE, plain, secrets.session)
    return out


def _open_share(secrets: VehicleSecrets, sender: int, blob: object, roster: dict[int, KeyAdvert]) -> tuple[int, int]:
    """The (s, b) shares that ``sender`` sealed for this vehicle; :class:`MessageError` if not authentic."""
    if not isinstance(blob, bytes) or len(blob) != _SEALED_NBYTES:
        raise MessageError(f"sealed shares from vehicle {sender}: expected {_SEALED_NBYTES} bytes")
    key = _seal_key(secrets, roster[sender].c_pk, sender, secrets.vehicle)
    try:
        plain = ChaCha20Poly1305(key).decrypt(_NONCE, blob, secrets.session)
    except InvalidTag as err:
        raise MessageError(f"sealed shares from vehicle {sender} failed authentication") from err
    if _PAIR.unpack_from(plain) != (sender, secrets.vehicle):
        raise MessageError(f"sealed shares from vehicle {sender}: wrong sender/recipient ids")
    s = int.from_bytes(plain[_PAIR.size:_PAIR.size + SHARE_NBYTES], "little")
    return s, int.from_bytes(plain[_PAIR.size + SHARE_NBYTES:], "little")


def _pair_mask(secrets_sk: bytes, me: int, other: int, other_pk: bytes, session: bytes,
               shape: tuple[int, ...]) -> np.ndarray:
    """``PRG(s_{me,other})`` signed for ``me``: ``+`` if ``me < other``, ``-`` (mod 2^64) otherwise."""
    seed = derive(x25519_agree(secrets_sk, other_pk, f"s_pk of vehicle {other}"), b"pair", session,
                  min(me, other), max(me, other))
    mask = prg_ring(seed, shape)
    return mask if me < other else np.negative(mask)


def mask_input(secrets: VehicleSecrets, z: ArrayLike, roster: dict[int, KeyAdvert], spec: SecAggSpec) -> MaskedInput:
    """Round 2: the masked contribution ``y_i`` of this vehicle (equation in the module docstring).

    Parameters
    ----------
    secrets : VehicleSecrets
    z : (L, 2) array_like
        This vehicle's inversion, m/s; clipped to ``[-spec.clip, spec.clip]``.
    roster : dict of int to KeyAdvert
        ``U_1``.
    spec : SecAggSpec

    Returns
    -------
    MaskedInput
    """
    ids = _check_roster(roster, spec, secrets)
    z = np.asarray(z, dtype=float)
    if z.ndim != 2 or z.shape[1] != 2 or z.shape[0] < 1 or not np.all(np.isfinite(z)):
        raise ParameterError(f"z must be a finite (L, 2) array, got shape {z.shape}")
    y = encode_fixed(z, spec.clip, spec.frac_bits)
    y = y + prg_ring(derive(secrets.b_seed, b"self", secrets.session, secrets.vehicle), z.shape)
    for j in ids:
        if j != secrets.vehicle:
            y = y + _pair_mask(secrets.s_sk, secrets.vehicle, j, roster[j].s_pk, secrets.session, z.shape)
    return MaskedInput(secrets.vehicle, y, session=secrets.session)


def reveal_shares(secrets: VehicleSecrets, sealed: dict[int, bytes], roster: dict[int, KeyAdvert],
                  survivors: Iterable[int], spec: SecAggSpec) -> Reveal:
    """Round 3: this vehicle's shares of ``b_i`` for ``i`` in ``survivors`` and of ``s_i`` for the rest.

    Parameters
    ----------
    secrets : VehicleSecrets
    sealed : dict of int to bytes
        Sender id -> the ciphertext it sealed for this vehicle in round 1 (forwarded, untrusted).
    roster : dict of int to KeyAdvert
        ``U_1``.
    survivors : iterable of int
        ``U_2`` as announced by the aggregator.
    spec : SecAggSpec

    Returns
    -------
    Reveal

    Raises
    ------
    AggregationRefused
        If fewer than ``k`` survivors are announced (an honest vehicle refuses to help unmask them).
    MessageError
        For a malformed announcement or sealed share.
    """
    ids = _check_roster(roster, spec, secrets)
    u2 = set(survivors)
    if not u2 <= set(ids):
        raise MessageError(f"announced survivors {sorted(u2 - set(ids))} are not in the roster")
    if len(u2) < spec.min_inputs:
        raise AggregationRefused(f"{len(u2)} survivors announced, at least k = {spec.min_inputs} required")
    me = secrets.vehicle
    s_own = shamir_split(secrets.s_sk, ids, spec.threshold, derive(secrets.share_seed, b"s", secrets.session))[me]
    b_own = shamir_split(secrets.b_seed, ids, spec.threshold, derive(secrets.share_seed, b"b", secrets.session))[me]
    shares = {me: (s_own, b_own)}
    for i in ids:
        if i != me:
            if i not in sealed:
                raise MessageError(f"no sealed shares from vehicle {i}")
            shares[i] = _open_share(secrets, i, sealed[i], roster)
    b = {i: sh[1] for i, sh in shares.items() if i in u2}
    s = {i: sh[0] for i, sh in shares.items() if i not in u2}
    return Reveal(me, b, s, session=secrets.session)


def _collect(reveals: Iterable[Reveal], field_name: str, owner: int) -> dict[int, int]:
    """``{holder: share}`` of ``owner``'s secret from every reveal that carries one."""
    return {r.vehicle: getattr(r, field_name)[owner] for r in reveals if owner in getattr(r, field_name)}


def unmask(roster: dict[int, KeyAdvert], masked: Iterable[MaskedInput], reveals: Iterable[Reveal], spec: SecAggSpec,
           session: bytes) -> AggregateResult:
    """The aggregator's last step: ``sum_{U_2} x_i`` from the masked inputs and the revealed shares.

    Parameters
    ----------
    roster : dict of int to KeyAdvert
        ``U_1``.
    masked : iterable of MaskedInput
        Round 2 messages (untrusted); their senders form ``U_2``.
    reveals : iterable of Reveal
        Round 3 messages (untrusted), at least ``t`` of them.
    spec : SecAggSpec
    session : bytes
        The session being aggregated (:func:`session_id`).

    Returns
    -------
    AggregateResult

    Raises
    ------
    AggregationRefused
        Fewer than ``k`` masked inputs, or fewer than ``t`` reveals.
    MessageError
        Inputs of different shapes, from another session or from outside the roster, inconsistent
        shares, or a reconstructed key that does not match its advertised public key.
    """
    by_vehicle = {m.vehicle: m for m in masked}
    answers = list(reveals)
    _check_session([*by_vehicle.values(), *answers], session)
    u2 = sorted(by_vehicle)
    if len(u2) < spec.min_inputs:
        raise AggregationRefused(f"{len(u2)} masked inputs, at least k = {spec.min_inputs} required")
    if len(answers) < spec.threshold:
        raise AggregationRefused(f"{len(answers)} vehicles answered, threshold t = {spec.threshold} required")
    if not set(u2) <= set(roster):
        raise MessageError(f"masked inputs from vehicles outside the roster: {sorted(set(u2) - set(roster))}")
    shape = by_vehicle[u2[0]].y.shape
    if any(m.y.shape != shape for m in by_vehicle.values()):
        raise MessageError("masked inputs have different shapes")
    total = np.zeros(shape, dtype=np.uint64)
    for i in u2:
        total += by_vehicle[i].y
        b_i = shamir_combine(_collect(answers, "self_mask_shares", i), spec.threshold, f"b of vehicle {i}")
        total -= prg_ring(derive(b_i, b"self", session, i), shape)
    dropped = tuple(sorted(set(roster) - set(u2)))
    for d in dropped:
        s_sk = shamir_combine(_collect(answers, "key_shares", d), spec.threshold, f"s_sk of vehicle {d}")
        if x25519_keypair(s_sk)[1] != roster[d].s_pk:
            raise MessageError(f"reconstructed s_sk of vehicle {d} does not match its advertised key")
        for j in u2:   # y_j carries +-PRG(s_jd); remove it
            total -= _pair_mask(s_sk, j, d, roster[j].s_pk, session, shape)
    return AggregateResult(decode_sum(total, spec.frac_bits), tuple(u2), dropped)

