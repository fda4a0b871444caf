"""Messages of secure aggregation (:mod:`roadcollab.privacy.secure_aggregation` runs the protocol).

One message type per round, between a vehicle and the aggregator: :class:`KeyAdvert` (round 0),
:class:`SealedShares` (round 1, forwarded by the aggregator), :class:`MaskedInput` (round 2) and
:class:`Reveal` (round 3). Every one is untrusted where it is received. Like
:class:`~.message.ExchangeMessage`, each runs every check of the codec when it is constructed
(:func:`~.describe.validate_message`), raising :class:`~roadcollab.errors.MessageError`: a message
that exists can be encoded and decoded. The byte layout is in :mod:`roadcollab.wire.protocol`.

``nbytes`` counts the fields a message carries (as the cost study always has); the encoded size adds
the 48-byte header, see :func:`~roadcollab.wire.protocol.message_nbytes`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .describe import validate_message
from .layout import (KEY_NBYTES, MESSAGE_TYPE_KEY_ADVERT, MESSAGE_TYPE_MASKED_INPUT, MESSAGE_TYPE_REVEAL,
                     MESSAGE_TYPE_SEALED_SHARES, SEALED_NBYTES, SECAGG_MECHANISM, SHARE_ENTRY_NBYTES)

__all__ = ["DEFAULT_SESSION", "KeyAdvert", "SealedShares", "MaskedInput", "Reveal"]

#: ``session_id(0, 0)``: segment 0, round 0 (the session :func:`run_secure_aggregation` uses by default).
DEFAULT_SESSION = bytes(16)
_ID_NBYTES = 4


class _SecAggMessage:
    """Common behaviour: validation on construction and the mechanism name."""

    WIRE_TYPE = 0

    def __post_init__(self) -> None:
        validate_message(self)

    @property
    def mechanism(self) -> str:
        """Always ``"secure_aggregation"``."""
        return SECAGG_MECHANISM


@dataclass(frozen=True)
class KeyAdvert(_SecAggMessage):
    """Round 0 message: ``vehicle`` (id) and its public keys ``c_pk``, ``s_pk`` (32 bytes each).

    Attributes
    ----------
    vehicle : int
        Sender id, in ``[1, 2^32 - 1]``.
    c_pk, s_pk : bytes
        Raw X25519 public keys (sealing shares, pairwise mask seeds), 32 bytes each.
    session : bytes
        16 bytes, ``session_id(segment, round)``.

    Raises
    ------
    MessageError
        On construction, if the message fails any check the codec applies.
    """

    WIRE_TYPE = MESSAGE_TYPE_KEY_ADVERT

    vehicle: int
    c_pk: bytes
    s_pk: bytes
    session: bytes = DEFAULT_SESSION

    @property
    def nbytes(self) -> int:
        """Field bytes: id (4) and two keys (64) = 68."""
        return _ID_NBYTES + 2 * KEY_NBYTES


@dataclass(frozen=True)
class SealedShares(_SecAggMessage):
    """Round 1 message: the shares ``sender`` sealed for ``recipient`` (the aggregator forwards it unread).

    Attributes
    ----------
    sender, recipient : int
        Vehicle ids, different, in ``[1, 2^32 - 1]``.
    ciphertext : bytes
        ChaCha20-Poly1305 of (sender, recipient, share of ``s_sk``, share of ``b``): 156 bytes.
    session : bytes
        16 bytes, ``session_id(segment, round)``.

    Raises
    ------
    MessageError
        On construction, if the message fails any check the codec applies.
    """

    WIRE_TYPE = MESSAGE_TYPE_SEALED_SHARES

    sender: int
    recipient: int
    ciphertext: bytes
    session: bytes = DEFAULT_SESSION

    @property
    def nbytes(self) -> int:
        """Field bytes: the ciphertext (156) and the recipient id (4) for routing = 160."""
        return SEALED_NBYTES + _ID_NBYTES


@dataclass(frozen=True)
class MaskedInput(_SecAggMessage):
    """Round 2 message (untrusted at the aggregator): ``vehicle`` and its masked ring vector ``y``.

    Attributes
    ----------
    vehicle : int
        Sender id, in ``[1, 2^32 - 1]``.
    y : (L, 2) ndarray of uint64
        ``x + PRG(b) + sum +-PRG(s_ij) mod 2^64``; uniform on the ring for anyone without the masks.
        ``1 <= L <= MAX_SIGNAL_LENGTH``.
    session : bytes
        16 bytes, ``session_id(segment, round)``.

    Raises
    ------
    MessageError
        If ``y`` is not a 2-D ``uint64`` array with 2 columns or ``vehicle`` is not a positive int
        (or any other check of the codec fails).
    """

    WIRE_TYPE = MESSAGE_TYPE_MASKED_INPUT

    vehicle: int
    y: np.ndarray
    session: bytes = DEFAULT_SESSION

    @property
    def nbytes(self) -> int:
        """Field bytes: id (4) and 8 bytes per ring element."""
        return _ID_NBYTES + self.y.nbytes


@dataclass(frozen=True)
class Reveal(_SecAggMessage):
    """Round 3 message of ``vehicle``: its shares ``{i: y}`` of ``b_i`` (survivors) and of ``s_i`` (dropped).

    Attributes
    ----------
    vehicle : int
        Holder id (the Shamir evaluation point of every share it reveals).
    self_mask_shares, key_shares : dict of int to int
        Owner id -> share in ``GF(2^521 - 1)``; an owner appears in at most one of them, and the
        two hold between 1 and ``MAX_VEHICLES`` shares together.
    session : bytes
        16 bytes, ``session_id(segment, round)``.

    Raises
    ------
    MessageError
        On construction, if the message fails any check the codec applies.
    """

    WIRE_TYPE = MESSAGE_TYPE_REVEAL

    vehicle: int
    self_mask_shares: dict[int, int] = field(default_factory=dict)
    key_shares: dict[int, int] = field(default_factory=dict)
    session: bytes = DEFAULT_SESSION

    @property
    def nbytes(self) -> int:
        """Field bytes: id (4), then per share an id (4) and 66 bytes."""
        return _ID_NBYTES + (len(self.self_mask_shares) + len(self.key_shares)) * SHARE_ENTRY_NBYTES
