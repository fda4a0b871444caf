"""Byte layout of the wire format: codes, ``struct`` headers, array order and sizes.

Described in full in :mod:`roadcollab.wire.protocol`. This module only states the layout;
whether a header's values are acceptable is decided in :mod:`~roadcollab.wire.limits`.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

import numpy as np

__all__ = [
    "MAGIC",
    "FORMAT_VERSION",
    "MESSAGE_TYPE_EXCHANGE",
    "MESSAGE_TYPE_INVERSION",
    "TYPE_NAMES",
    "MECHANISM_CODES",
    "MECHANISM_NAMES",
    "MECHANISM_TYPE",
    "COMMON_STRUCT",
    "EXCHANGE_EXT_STRUCT",
    "INVERSION_EXT_STRUCT",
    "COMMON_HEADER_NBYTES",
    "EXCHANGE_HEADER_NBYTES",
    "INVERSION_HEADER_NBYTES",
    "F8",
    "FLOAT_NBYTES",
    "CHANNELS",
    "exchange_nbytes",
    "inversion_nbytes",
    "Header",
    "payload_shapes",
    "PREFIX_STRUCT",
    "MESSAGE_TYPE_KEY_ADVERT",
    "MESSAGE_TYPE_SEALED_SHARES",
    "MESSAGE_TYPE_MASKED_INPUT",
    "MESSAGE_TYPE_REVEAL",
    "SECAGG_TYPES",
    "SECAGG_MECHANISM",
    "SECAGG_STRUCT",
    "SECAGG_HEADER_NBYTES",
    "KEY_NBYTES",
    "SHARE_NBYTES",
    "AEAD_TAG_NBYTES",
    "SEALED_NBYTES",
    "SHARE_ENTRY_NBYTES",
    "U8",
    "SecAggHeader",
]

MAGIC = b"RCOL"
FORMAT_VERSION = 1

MESSAGE_TYPE_EXCHANGE = 1
MESSAGE_TYPE_INVERSION = 2
# Secure aggregation (roadcollab.privacy.secure_aggregation), vehicle <-> aggregator, one type per round.
MESSAGE_TYPE_KEY_ADVERT = 3       # round 0: two X25519 public keys
MESSAGE_TYPE_SEALED_SHARES = 4    # round 1: AEAD-sealed Shamir shares for one recipient
MESSAGE_TYPE_MASKED_INPUT = 5     # round 2: the masked ring vector y
MESSAGE_TYPE_REVEAL = 6           # round 3: shares of b_i (survivors) and s_i (dropped)
SECAGG_TYPES = (MESSAGE_TYPE_KEY_ADVERT, MESSAGE_TYPE_SEALED_SHARES, MESSAGE_TYPE_MASKED_INPUT, MESSAGE_TYPE_REVEAL)
TYPE_NAMES = {MESSAGE_TYPE_EXCHANGE: "exchange", MESSAGE_TYPE_INVERSION: "inversion",
              MESSAGE_TYPE_KEY_ADVERT: "key_advert", MESSAGE_TYPE_SEALED_SHARES: "sealed_shares",
              MESSAGE_TYPE_MASKED_INPUT: "masked_input", MESSAGE_TYPE_REVEAL: "reveal"}

# Codes start at 1 so that an all-zero header can never be a valid message.
SECAGG_MECHANISM = "secure_aggregation"
MECHANISM_CODES = {"none": 1, "paper": 2, "hardened": 3, "fused": 4, SECAGG_MECHANISM: 5}
MECHANISM_NAMES = {code: name for name, code in MECHANISM_CODES.items()}
# The message type of each mechanism; secure_aggregation has four (SECAGG_TYPES), its example is a masked input.
MECHANISM_TYPE = {"none": MESSAGE_TYPE_EXCHANGE, "paper": MESSAGE_TYPE_EXCHANGE,
                  "hardened": MESSAGE_TYPE_INVERSION, "fused": MESSAGE_TYPE_INVERSION,
                  SECAGG_MECHANISM: MESSAGE_TYPE_MASKED_INPUT}

# The first 8 bytes (magic, version, type, mechanism, reserved) are common to every message type.
PREFIX_STRUCT = struct.Struct("<4sBBBB")
COMMON_STRUCT = struct.Struct("<4sBBBBdIIQ")
EXCHANGE_EXT_STRUCT = struct.Struct("<IIdd")
INVERSION_EXT_STRUCT = struct.Struct("<II")

COMMON_HEADER_NBYTES = COMMON_STRUCT.size                                # 32
EXCHANGE_HEADER_NBYTES = COMMON_STRUCT.size + EXCHANGE_EXT_STRUCT.size   # 56
INVERSION_HEADER_NBYTES = COMMON_STRUCT.size + INVERSION_EXT_STRUCT.size  # 40

F8 = np.dtype("<f8")
FLOAT_NBYTES = F8.itemsize
CHANNELS = 2  # every system is 2x2 and every signal has two channels (left, right track)


def _system_floats(order: int) -> int:
    """Entries of A, B, C, D of a 2x2 system of the given order: ``(order + 2)**2``."""
    return (order + CHANNELS) ** 2


def exchange_nbytes(order_T: int, order_S: int, length: int) -> int:
    """Encoded size of an :class:`ExchangeMessage`.

    Parameters
    ----------
    order_T, order_S : int
        State dimensions of ``T`` and ``S``.
    length : int
        Rows ``L`` of ``e`` and ``wf``.

    Returns
    -------
    int
        ``56 + 8 * ((order_T + 2)**2 + (order_S + 2)**2 + 4 * length)``.
    """
    floats = _system_floats(order_T) + _system_floats(order_S) + 2 * CHANNELS * length
    return EXCHANGE_HEADER_NBYTES + FLOAT_NBYTES * floats


def inversion_nbytes(length: int) -> int:
    """Encoded size of an :class:`InversionMessage` with ``z`` of ``length`` rows: ``40 + 16 * length``.

    Parameters
    ----------
    length : int
        Rows ``L`` of ``z``.

    Returns
    -------
    int
        Bytes.
    """
    return INVERSION_HEADER_NBYTES + FLOAT_NBYTES * CHANNELS * length


class Header(NamedTuple):
    """All header fields, for both message types (unused ones are 0).

    Parameters
    ----------
    msg_type : int
        ``MESSAGE_TYPE_EXCHANGE`` or ``MESSAGE_TYPE_INVERSION``.
    mechanism : str
        A key of ``MECHANISM_CODES``.
    sample_rate : float
        Hz.
    n_samples : int
        Samples in the recorded window.
    length : int
        Rows ``L`` of every (L, 2) signal.
    payload_nbytes : int
        Payload byte count as declared (decode) or implied by the dimensions (encode).
    order_T, order_S : int
        State dimensions of ``T`` and ``S`` (exchange only).
    dt_T, dt_S : float
        Sample times of ``T`` and ``S``, s (exchange only).
    count : int
        Vehicles whose inversions ``z`` averages (inversion only).
    """

    msg_type: int
    mechanism: str
    sample_rate: float
    n_samples: int
    length: int
    payload_nbytes: int
    order_T: int = 0
    order_S: int = 0
    dt_T: float = 0.0
    dt_S: float = 0.0
    # the wire field ``count`` shadows tuple.count (a method) on purpose: it is the message's field name
    count: int = 0  # type: ignore[assignment]

    @property
    def header_nbytes(self) -> int:
        """Size of the full header (common part and type extension), bytes."""
        return EXCHANGE_HEADER_NBYTES if self.msg_type == MESSAGE_TYPE_EXCHANGE else INVERSION_HEADER_NBYTES

    def expected_payload_nbytes(self) -> int:
        """Payload size implied by the dimensions, bytes."""
        if self.msg_type == MESSAGE_TYPE_EXCHANGE:
            return exchange_nbytes(self.order_T, self.order_S, self.length) - EXCHANGE_HEADER_NBYTES
        return inversion_nbytes(self.length) - INVERSION_HEADER_NBYTES


def payload_shapes(h: Header) -> list[tuple[str, tuple[int, int]]]:
    """Names and shapes of the payload arrays, in wire order.

    Parameters
    ----------
    h : Header

    Returns
    -------
    list of (str, (int, int))
        ``"T.A"``, ..., ``"S.D"``, ``"e"``, ``"wf"`` for an exchange message, ``"z"`` for an
        inversion message.
    """
    if h.msg_type == MESSAGE_TYPE_INVERSION:
        return [("z", (h.length, CHANNELS))]
    shapes = []
    for name, n in (("T", h.order_T), ("S", h.order_S)):
        shapes += [(f"{name}.A", (n, n)), (f"{name}.B", (n, CHANNELS)),
                   (f"{name}.C", (CHANNELS, n)), (f"{name}.D", (CHANNELS, CHANNELS))]
    return shapes + [("e", (h.length, CHANNELS)), ("wf", (h.length, CHANNELS))]


# --- secure aggregation ------------------------------------------------------------------------
# prefix, session (segment, round), payload byte count, sender, two type-dependent counts, reserved.
SECAGG_STRUCT = struct.Struct("<4sBBBB16sQIIII")
SECAGG_HEADER_NBYTES = SECAGG_STRUCT.size   # 48
KEY_NBYTES = 32               # a raw X25519 public key
SHARE_NBYTES = 66             # a Shamir share y in GF(2^521 - 1): ceil(521 / 8) bytes, little-endian
AEAD_TAG_NBYTES = 16          # Poly1305 tag of ChaCha20-Poly1305
_ID_NBYTES = 4
# Sealed plaintext: sender and recipient ids, the share of s_i and the share of b_i; then the tag.
SEALED_NBYTES = 2 * _ID_NBYTES + 2 * SHARE_NBYTES + AEAD_TAG_NBYTES   # 156
SHARE_ENTRY_NBYTES = _ID_NBYTES + SHARE_NBYTES                        # owner id, share: 70
U8 = np.dtype("<u8")


class SecAggHeader(NamedTuple):
    """The 48-byte header of a secure-aggregation message (``struct`` format ``"<4sBBBB16sQIIII"``).

    Parameters
    ----------
    msg_type : int
        One of ``SECAGG_TYPES``.
    session : bytes
        16 bytes: segment and round, two little-endian uint64 (``privacy.secagg_messages.session_id``).
    payload_nbytes : int
        As declared (decode) or implied by the counts (encode).
    vehicle : int
        Sender id (>= 1).
    n1 : int
        Recipient id (sealed shares), rows ``L`` of ``y`` (masked input), entries of
        ``self_mask_shares`` (reveal); 0 for a key advert.
    n2 : int
        Entries of ``key_shares`` (reveal); 0 otherwise.
    reserved : int
        Must be 0.
    mechanism : str
        As named by the mechanism byte; must be ``"secure_aggregation"``.
    """

    msg_type: int
    session: bytes
    payload_nbytes: int
    vehicle: int
    n1: int = 0
    n2: int = 0
    reserved: int = 0
    mechanism: str = SECAGG_MECHANISM

    @property
    def header_nbytes(self) -> int:
        """Size of the header, bytes (48)."""
        return SECAGG_HEADER_NBYTES

    def expected_payload_nbytes(self) -> int:
        """Payload size implied by the type and counts, bytes.

        Returns
        -------
        int
            64 (key advert), 156 (sealed shares), ``16 * L`` (masked input) or ``70 * (n1 + n2)`` (reveal).
        """
        if self.msg_type == MESSAGE_TYPE_KEY_ADVERT:
            return 2 * KEY_NBYTES
        if self.msg_type == MESSAGE_TYPE_SEALED_SHARES:
            return SEALED_NBYTES
        if self.msg_type == MESSAGE_TYPE_MASKED_INPUT:
            return U8.itemsize * CHANNELS * self.n1
        return SHARE_ENTRY_NBYTES * (self.n1 + self.n2)
