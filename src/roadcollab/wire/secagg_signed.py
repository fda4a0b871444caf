"""Signed messages of secure aggregation against an active aggregator (Bonawitz et al. 2017, Fig. 4 "active").

Three signed messages travel besides the semi-honest ones of :mod:`.secagg`, each a signed envelope
(:mod:`.envelope`: the vehicle's fleet certificate, the payload and its Ed25519 signature) whose
context binds the purpose and the 16-byte session (segment, epoch), so none verifies in another
round or session:

- **signed advert** (round 0): the encoded :class:`~.secagg.KeyAdvert`. It binds the vehicle's
  protocol id and its two X25519 keys to its certificate: an aggregator can neither invent a vehicle
  (Sybil) nor swap in its own keys (key substitution).
- **share commitments** (round 1): for every holder ``j`` of the roster, ``H(s share for j)`` and
  ``H(b share for j)``, and ``H(b)``: a revealed share that is not the one dealt is identified
  (and excluded) by anyone, and a reconstructed ``b`` is checked.
- **consistency signature** (round 2.5): the vehicle's signature of the survivor set ``U_3`` it
  was shown; a vehicle reveals only with ``t`` signatures of members of ``U_3`` on the same set.

Payload layouts (little-endian, as :mod:`.protocol`)::

    advert      := encode(KeyAdvert)
    commitments := u32 dealer | 32-byte H(b) | u32 m | m x (u32 holder | 32-byte H(s_j) | 32-byte H(b_j))
    view        := u32 signer | u32 m | m x u32 id (strictly increasing)
"""

from __future__ import annotations

import hashlib
import struct
from collections.abc import Iterable
from dataclasses import dataclass

from ..errors import MessageError
from .envelope import open_envelope, seal_envelope
from .identity import Certificate, FleetTrust, VehicleIdentity
from .protocol import decode, encode
from .secagg import KeyAdvert

__all__ = ["ADVERT_CONTEXT", "COMMIT_CONTEXT", "VIEW_CONTEXT", "HASH_NBYTES", "share_hash", "secret_hash",
           "ShareCommitments", "sign_advert", "open_advert", "sign_commitments", "open_commitments", "sign_view",
           "open_view"]

ADVERT_CONTEXT = b"roadcollab/secagg/advert/v1\x00"
COMMIT_CONTEXT = b"roadcollab/secagg/commitments/v1\x00"
VIEW_CONTEXT = b"roadcollab/secagg/view/v1\x00"
HASH_NBYTES = 32
_HASH_DOMAIN = b"roadcollab/secagg/share-hash/v1\x00"
_U32 = struct.Struct("<I")
_MAX_IDS = 65536


def share_hash(session: bytes, dealer: int, holder: int, kind: bytes, share: int) -> bytes:
    """``SHA-256`` commitment to one Shamir share (``kind`` ``b"s"`` or ``b"b"``), bound to its route.

    A share is a uniform element of ``GF(2^521 - 1)`` to anyone holding fewer than ``t`` shares, so the
    unsalted hash hides it; binding the session, dealer and holder stops a share being replayed elsewhere.

    Parameters
    ----------
    session : bytes
        16 bytes, ``session_id(segment, epoch)``.
    dealer, holder : int
        Protocol ids.
    kind : bytes
        ``b"s"`` (share of ``s_sk``) or ``b"b"`` (share of ``b``).
    share : int
        The share, in ``GF(2^521 - 1)``.

    Returns
    -------
    bytes
        32 bytes.
    """
    return hashlib.sha256(_HASH_DOMAIN + session + struct.pack("<II", dealer, holder) + kind
                          + int(share).to_bytes(66, "little")).digest()


def secret_hash(session: bytes, dealer: int, secret: bytes) -> bytes:
    """``SHA-256`` commitment to a dealer's 32-byte self-mask seed ``b``.

    Parameters
    ----------
    session : bytes
        16 bytes, ``session_id(segment, epoch)``.
    dealer : int
    secret : bytes
        ``b``, 32 bytes.

    Returns
    -------
    bytes
    """
    return hashlib.sha256(_HASH_DOMAIN + session + _U32.pack(dealer) + b"B" + bytes(secret)).digest()


@dataclass(frozen=True)
class ShareCommitments:
    """A dealer's signed commitments: ``H(b)`` and, per holder, the hashes of its two shares.

    Attributes
    ----------
    dealer : int
        Protocol id of the dealer.
    b_hash : bytes
        :func:`secret_hash` of the dealer's ``b`` (32 bytes).
    shares : dict of int to (bytes, bytes)
        Holder id -> (:func:`share_hash` of the ``s`` share, of the ``b`` share).
    """

    dealer: int
    b_hash: bytes
    shares: dict[int, tuple[bytes, bytes]]

    def to_bytes(self) -> bytes:
        """The payload (module docstring)."""
        rows = b"".join(_U32.pack(j) + hs + hb for j, (hs, hb) in sorted(self.shares.items()))
        return _U32.pack(self.dealer) + self.b_hash + _U32.pack(len(self.shares)) + rows

    @classmethod
    def from_bytes(cls, data: bytes) -> "ShareCommitments":
        """Parse an (untrusted) payload; :class:`MessageError` if malformed.

        Parameters
        ----------
        data : bytes

        Returns
        -------
        ShareCommitments
        """
        head = 4 + HASH_NBYTES + 4
        row = 4 + 2 * HASH_NBYTES
        if len(data) < head:
            raise MessageError(f"share commitments: truncated ({len(data)} bytes)")
        dealer, m = _U32.unpack_from(data, 0)[0], _U32.unpack_from(data, 4 + HASH_NBYTES)[0]
        if m > _MAX_IDS or len(data) != head + m * row:
            raise MessageError(f"share commitments: {len(data)} bytes do not hold {m} entries")
        shares: dict[int, tuple[bytes, bytes]] = {}
        for k in range(m):
            at = head + k * row
            j = _U32.unpack_from(data, at)[0]
            if j in shares:
                raise MessageError(f"share commitments of vehicle {dealer}: holder {j} twice")
            shares[j] = (data[at + 4:at + 4 + HASH_NBYTES], data[at + 4 + HASH_NBYTES:at + row])
        return cls(dealer, data[4:4 + HASH_NBYTES], shares)


def sign_advert(identity: VehicleIdentity, advert: KeyAdvert) -> bytes:
    """The signed advert envelope of ``advert`` (context: purpose and session).

    Parameters
    ----------
    identity : VehicleIdentity
        The vehicle's fleet identity.
    advert : KeyAdvert

    Returns
    -------
    bytes
    """
    return seal_envelope(identity, encode(advert), ADVERT_CONTEXT + advert.session)


def open_advert(data: bytes, trust: FleetTrust, session: bytes) -> tuple[Certificate, KeyAdvert]:
    """Check a signed advert of ``session`` against the fleet's trust anchor.

    Parameters
    ----------
    data : bytes
        The envelope (untrusted).
    trust : FleetTrust
    session : bytes

    Returns
    -------
    (Certificate, KeyAdvert)

    Raises
    ------
    MessageError
        Not a certified vehicle of the fleet, revoked, a bad signature (another session included),
        or a payload that is not a key advert of ``session``.
    """
    cert, payload = open_envelope(data, trust, ADVERT_CONTEXT + session)
    advert = decode(payload)
    if not isinstance(advert, KeyAdvert) or advert.session != session:
        raise MessageError(f"signed advert of {cert.vehicle_id!r}: not a key advert of this session")
    return cert, advert


def sign_commitments(identity: VehicleIdentity, session: bytes, commitments: ShareCommitments) -> bytes:
    """The signed envelope of a dealer's :class:`ShareCommitments` in ``session``.

    Parameters
    ----------
    identity : VehicleIdentity
    session : bytes
    commitments : ShareCommitments

    Returns
    -------
    bytes
    """
    return seal_envelope(identity, commitments.to_bytes(), COMMIT_CONTEXT + session)


def open_commitments(data: bytes, trust: FleetTrust, session: bytes) -> tuple[Certificate, ShareCommitments]:
    """Check and parse a signed :class:`ShareCommitments` envelope of ``session``.

    Parameters
    ----------
    data : bytes
    trust : FleetTrust
    session : bytes

    Returns
    -------
    (Certificate, ShareCommitments)

    Raises
    ------
    MessageError
        Bad envelope or signature, or a malformed payload.
    """
    cert, payload = open_envelope(data, trust, COMMIT_CONTEXT + session)
    return cert, ShareCommitments.from_bytes(payload)


def _view_payload(signer: int, view: Iterable[int]) -> bytes:
    ids = sorted(view)
    return _U32.pack(signer) + _U32.pack(len(ids)) + b"".join(_U32.pack(i) for i in ids)


def sign_view(identity: VehicleIdentity, session: bytes, signer: int, view: Iterable[int]) -> bytes:
    """The consistency signature of vehicle ``signer`` on the survivor set ``view`` (``U_3``) of ``session``.

    Parameters
    ----------
    identity : VehicleIdentity
    session : bytes
    signer : int
    view : iterable of int

    Returns
    -------
    bytes
    """
    return seal_envelope(identity, _view_payload(signer, view), VIEW_CONTEXT + session)


def open_view(data: bytes, trust: FleetTrust, session: bytes) -> tuple[Certificate, int, tuple[int, ...]]:
    """Check a consistency signature of ``session``: ``(certificate, signer id, sorted view)``.

    Parameters
    ----------
    data : bytes
    trust : FleetTrust
    session : bytes

    Returns
    -------
    (Certificate, int, tuple of int)

    Raises
    ------
    MessageError
        Bad envelope or signature, malformed payload, or ids not strictly increasing.
    """
    cert, payload = open_envelope(data, trust, VIEW_CONTEXT + session)
    if len(payload) < 8:
        raise MessageError(f"consistency signature of {cert.vehicle_id!r}: truncated")
    signer, m = _U32.unpack_from(payload, 0)[0], _U32.unpack_from(payload, 4)[0]
    if m > _MAX_IDS or len(payload) != 8 + 4 * m:
        raise MessageError(f"consistency signature of {cert.vehicle_id!r}: {len(payload)} bytes for {m} ids")
    ids = tuple(_U32.unpack_from(payload, 8 + 4 * k)[0] for k in range(m))
    if any(b <= a for a, b in zip(ids, ids[1:])):
        raise MessageError(f"consistency signature of {cert.vehicle_id!r}: ids not strictly increasing")
    return cert, signer, ids
